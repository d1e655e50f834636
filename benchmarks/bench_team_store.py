"""Load and fault test of the team label store: 2 servers × 8 annotators, 2,000 edges.

Each "studio server" is a process with one store (as ``vgm-studio label`` holds one); its 8
annotators are threads that call the store exactly as the studio does on a label press
(``claim`` the next edge, then ``label``), through the store API, not websockets. On
PostgreSQL the claim is the store's cross-server claim; the SQLite run splits the queue
between annotators up front (its claims live in one server's memory), so only label latency
is compared. Then the PostgreSQL run again with ``pg_ctl restart`` in the middle.

Checks: 0 labels lost (every acknowledged label is in the store), 0 edges labelled twice,
p50/p95 latency of one label press. Bounded (a few minutes), loopback only.

    python benchmarks/bench_team_store.py [--edges 2000] [--servers 2] [--annotators 8]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._common import machine, table
from benchmarks.pg_local import LocalPostgres, pg_bin
from vgm_studio.labels.opening import open_store
from vgm_studio.matching.edges import Edge


def _edges(count: int) -> list[Edge]:
    """Synthetic edges: the label path reads only their ids."""
    return [
        Edge(
            f"{i:016x}",
            "bench",
            "0" * 64,
            i,
            i + 1,
            float(i),
            i + 1.0,
            "loop",
            [0.0] * 3,
            [0.0] * 3,
        )
        for i in range(count)
    ]


def _next_free(store, name: str, queue: list[str], pos: int) -> int | None:
    """What the studio's move does: read the labels, claim the next unlabelled edge."""
    labels = store.label_map()
    store.release(name)
    for i in range(pos, len(queue)):
        if queue[i] not in labels and store.claim(queue[i], name):
            return i
    return None


def _annotate(store, name: str, queue: list[str], team: bool, out: dict) -> None:
    latencies, acked = [], []
    pos: int | None = 0
    while True:
        pos = _next_free(store, name, queue, pos or 0) if team else pos
        if pos is None or pos >= len(queue):
            break
        start = time.perf_counter()
        store.label(queue[pos], name, "success")
        latencies.append(time.perf_counter() - start)
        acked.append(queue[pos])
        pos += 1
    out[name] = (latencies, acked)


def _server(
    index: int, where: tuple[str, str | None], ids: list[str], annotators: int, total: int, results
) -> None:
    folder, url = where
    store = open_store(Path(folder), url)
    out: dict = {}
    threads = []
    for a in range(annotators):
        k = index * annotators + a
        # PostgreSQL: everyone walks the queue from their own place; claims split it.
        cut = k * len(ids) // total
        queue = ids[cut:] + ids[:cut] if url else ids[k::total]
        threads.append(
            threading.Thread(target=_annotate, args=(store, f"s{index}a{a}", queue, bool(url), out))
        )
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    results.put((out, getattr(store, "reconnects", 0)))
    store.close()


def _run(
    where: tuple[str, str | None], edges: list[Edge], servers: int, annotators: int, fault=None
) -> dict:
    folder, url = where
    store = open_store(Path(folder), url)
    store.add_edges(edges)
    ids = store.edge_ids()
    results: mp.Queue = mp.Queue()
    procs = [
        mp.Process(target=_server, args=(i, where, ids, annotators, servers * annotators, results))
        for i in range(servers)
    ]
    start = time.perf_counter()
    for p in procs:
        p.start()
    if fault:
        fault(store)
    gathered = [results.get(timeout=900) for _ in procs]
    for p in procs:
        p.join()
    seconds = time.perf_counter() - start
    latencies = [x for out, _ in gathered for lat, _ in out.values() for x in lat]
    acked = [e for out, _ in gathered for _, ack in out.values() for e in ack]
    labels = store.label_map()
    store.close()
    q = statistics.quantiles(latencies, n=100)
    return {
        "labels": len(acked),
        "lost": len(set(acked) - set(labels)),
        "twice": sum(1 for v in labels.values() if len(v) > 1) + len(acked) - len(set(acked)),
        "p50": q[49] * 1000,
        "p95": q[94] * 1000,
        "rate": len(acked) / seconds,
        "reconnects": sum(r for _, r in gathered),
    }


def _restart_midway(server: LocalPostgres, edges: int):
    def fault(store) -> None:
        while sum(len(v) for v in store.label_map().values()) < edges // 2:
            time.sleep(0.05)
        start = time.perf_counter()
        server.restart()
        print(f"restarted the server in {time.perf_counter() - start:.1f} s", flush=True)

    return fault


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--edges", type=int, default=2000)
    parser.add_argument("--servers", type=int, default=2)
    parser.add_argument("--annotators", type=int, default=8)
    args = parser.parse_args()
    bindir = pg_bin()
    if bindir is None:
        sys.exit("PostgreSQL binaries not found (apt install postgresql)")
    edges = _edges(args.edges)
    server = LocalPostgres(bindir)
    server.start()
    rows = []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            runs = [
                ("SQLite (WAL, FULL)", (f"{tmp}/ws", None), None),
                ("PostgreSQL", (f"{tmp}/m1", server.new_database("bench")), None),
            ]
            url = server.new_database("fault")
            runs.append(
                (
                    "PostgreSQL, restarted mid-run",
                    (f"{tmp}/m2", url),
                    _restart_midway(server, args.edges),
                )
            )
            for name, where, fault in runs:
                r = _run(where, edges, args.servers, args.annotators, fault)
                rows.append(
                    [
                        name,
                        str(r["labels"]),
                        str(r["lost"]),
                        str(r["twice"]),
                        f"{r['p50']:.1f}",
                        f"{r['p95']:.1f}",
                        f"{r['rate']:.0f}",
                        str(r["reconnects"]),
                    ]
                )
                print(rows[-1], flush=True)
    finally:
        server.stop()
    load = f"{args.servers} servers × {args.annotators} annotators, {args.edges} edges"
    print(f"\n{load}; {machine()}\n")
    header = ["store", "labels", "lost", "twice", "p50 ms", "p95 ms", "labels/s", "reconnects"]
    print(table(header, rows))


if __name__ == "__main__":
    main()
