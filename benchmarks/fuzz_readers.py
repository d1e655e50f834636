"""A larger fuzz campaign over every reader and ``import`` than the CI suite runs.

Usage (from the repository root, a few minutes on one core):
    PYTHONPATH=. nice -n 10 python benchmarks/fuzz_readers.py --cases 1000 --cli 40

Each case mutates a valid file with the operations of tests/fuzzing.py (drawn by a seeded
``random.Random``) and calls the reader in-process; it must accept the file or raise one clean
``InputError``. A refused import must leave every row of the store as it was. ``--cli`` cases
run the real command line and check the exit code (0 or 1), one stderr line and no traceback.
Prints one table row per reader.
"""

from __future__ import annotations

import argparse
import json
import random
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter
from collections.abc import Callable
from pathlib import Path

from _common import REPO, machine, table

sys.path.insert(0, str(REPO))

from tests.fuzzing import (
    BYTE_OPS,
    BYTE_PAYLOADS,
    VALUE_PAYLOADS,
    Op,
    check_outcome,
    mutate_bytes,
    mutate_json_rows,
    store_rows,
)
from tests.untrusted import seed_files
from vgm_studio.datasets import open_log
from vgm_studio.datasets.options import ReadOptions
from vgm_studio.datasets.relations import read_relations
from vgm_studio.labels import LabelStore
from vgm_studio.labels.transfer import import_labels
from vgm_studio.matching.edges import read_edges


def _byte_ops(rng: random.Random) -> list[Op]:
    return [
        (rng.choice(BYTE_OPS), rng.random(), rng.randrange(10 * len(BYTE_PAYLOADS)))
        for _ in range(rng.randint(1, 4))
    ]


def _field_ops(rng: random.Random) -> list[Op]:
    return [
        ("field", rng.random(), rng.randrange(40 * len(VALUE_PAYLOADS)))
        for _ in range(rng.randint(1, 3))
    ]


def _mutant(seeds: dict[str, Path], kind: str, rng: random.Random) -> bytes:
    source = seeds[kind]
    if kind in ("edges", "labels.jsonl") and rng.random() < 0.5:
        rows = [json.loads(x) for x in source.read_text().splitlines()]
        return mutate_json_rows(rows, _field_ops(rng))
    return mutate_bytes(source.read_bytes(), _byte_ops(rng))


def _campaign(
    seeds: dict[str, Path], store: LabelStore, cases: int, rng: random.Random
) -> list[list[str]]:
    folder = seeds["log"].parent
    readers: dict[str, tuple[str, str, Callable[[Path], object]]] = {
        "CARMEN log": ("log", ".log", lambda p: open_log(p, ReadOptions())),
        "relations": ("relations", ".relations", read_relations),
        "edges JSONL": ("edges", ".jsonl", read_edges),
        "import JSONL": ("labels.jsonl", ".jsonl", lambda p: import_labels(store, p)),
        "import CSV": ("labels.csv", ".csv", lambda p: import_labels(store, p)),
    }
    rows = []
    for name, (kind, suffix, reader) in readers.items():
        outcomes: Counter[str] = Counter()
        start = time.perf_counter()
        for i in range(cases):
            path = folder / f"case-{i}{suffix}"
            path.write_bytes(_mutant(seeds, kind, rng))
            before = store_rows(store.path) if name.startswith("import") else None
            try:
                outcome = check_outcome(lambda p=path, r=reader: r(p))  # type: ignore[misc]
                if outcome == "refused" and before is not None and store_rows(store.path) != before:
                    outcome = "store changed"
            except Exception:
                outcome = "crash"
                print(f"{name} case {i}:\n{traceback.format_exc()}", file=sys.stderr)
            outcomes[outcome] += 1
            path.unlink()
        seconds = time.perf_counter() - start
        rows.append(
            [
                name,
                str(cases),
                str(outcomes["ok"]),
                str(outcomes["refused"]),
                str(outcomes["crash"] + outcomes["store changed"]),
                f"{1000 * seconds / cases:.1f}",
            ]
        )
    return rows


def _cli(seeds: dict[str, Path], count: int, rng: random.Random) -> list[str]:
    commands = [("info", "log"), ("info", "relations"), ("import", "labels.jsonl")]
    commands.append(("import", "labels.csv"))
    outcomes: Counter[str] = Counter()
    folder = seeds["log"].parent
    for i in range(count):
        command, kind = commands[i % len(commands)]
        path = folder / f"cli-{i}{seeds[kind].suffix}"
        path.write_bytes(_mutant(seeds, kind, rng))
        extra = ["--workspace", str(folder / f"ws-{i}")] if command == "import" else ["--json"]
        args = [str(path), *extra]
        proc = subprocess.run(
            [sys.executable, "-m", "vgm_studio.tools.cmd", command, *args],
            capture_output=True,
            text=True,
            timeout=120,
        )
        clean = (
            proc.returncode in (0, 1)
            and "Traceback" not in proc.stderr
            and len(proc.stderr.strip().splitlines()) <= 1
            and (command != "info" or proc.returncode != 0 or _standard_json(proc.stdout))
        )
        outcomes["ok" if proc.returncode == 0 and clean else "refused" if clean else "bad"] += 1
        if not clean:
            print(f"cli {command} case {i}: rc {proc.returncode}\n{proc.stderr}", file=sys.stderr)
    return [
        "command line",
        str(count),
        str(outcomes["ok"]),
        str(outcomes["refused"]),
        str(outcomes["bad"]),
        "",
    ]


def _standard_json(text: str) -> bool:
    """True when ``text`` is JSON without the NaN/Infinity tokens Python's json allows."""

    def refuse(name: str) -> None:
        raise ValueError(name)

    try:
        json.loads(text, parse_constant=refuse)
    except ValueError:
        return False
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=1000, help="Cases per reader.")
    parser.add_argument("--cli", type=int, default=40, help="Command-line cases.")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        seeds = seed_files(Path(tmp))
        store = LabelStore(Path(tmp) / "target")
        import_labels(store, seeds["labels.jsonl"])
        rows = _campaign(seeds, store, args.cases, rng)
        rows.append(_cli(seeds, args.cli, rng))
    print(f"fuzz_readers: seed {args.seed}, {machine()}")
    header = ["reader", "cases", "accepted", "refused (1 line)", "crash/changed", "ms/case"]
    print(table(header, rows))


if __name__ == "__main__":
    main()
