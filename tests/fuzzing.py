"""Mutations of valid files, shared by tests/test_fuzz.py and benchmarks/fuzz_readers.py.

A mutation is a list of operations, each ``(kind, where, what)`` with ``where`` in [0, 1) a
position in the file (or the row, field) and ``what`` an index into a payload list: the same
operations give the same file, whether hypothesis or a seeded ``random.Random`` chose them.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from vgm_studio.errors import InputError

# The payload classes of issue 13, and their neighbours.
BYTE_PAYLOADS: tuple[bytes, ...] = (
    b"Infinity",
    b"-Infinity",
    b"NaN",
    b"nan",
    b"inf",
    b"1e999",
    b"4e38",
    b"-1",
    b"0",
    b"null",
    b'"x"',
    b"[" * 200_000,
    b"9" * 5000,
    b'"\\ud800"',
    b"\x1b[31m",
    b"\x00",
    b"\xff\xfe",
    b"{}",
    b"[]",
    b"true",
    b'=HYPERLINK("http://x","y")',
    b"@SUM(A1)",
    b",",
    b"\n",
    b"\r",
    b'"',
    "\u2028".encode(),
    "é".encode(),
    b"a" * 140_000,
    b"/proc/self/environ",
)
VALUE_PAYLOADS: tuple[Any, ...] = (
    None,
    True,
    0,
    -1,
    10**400,
    1.5,
    float("nan"),
    float("inf"),
    -float("inf"),
    4e38,
    "",
    "x",
    "\ud800",
    "\x00",
    "=1+2",
    "x" * 5000,
    "/proc/self/environ",
    "2026-01-01T13:00:00+05:00",
    "2026-01-01T12:00:00",
    [],
    [1, 2],
    [0, 0, "x"],
    [float("nan"), 0, 0],
    {},
    {"a": {"b": {"c": [[[[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]]]}}},
    "sequential",
    "success",
)
BYTE_OPS = ("insert", "replace", "delete", "flip", "duplicate", "truncate")
Op = tuple[str, float, int]


def _at(data: bytes, where: float) -> int:
    return min(int(where * (len(data) + 1)), len(data))


def _token_span(data: bytes, i: int) -> tuple[int, int]:
    """The bytes around ``i`` up to the nearest separator either side."""
    seps = b" \n,:[]{}\t"
    start, end = i, i
    while start > 0 and data[start - 1] not in seps:
        start -= 1
    while end < len(data) and data[end] not in seps:
        end += 1
    return start, end


def mutate_bytes(data: bytes, ops: Sequence[Op]) -> bytes:
    """Applies byte-level operations: insert or substitute payloads, delete, flip, cut."""
    for kind, where, what in ops:
        i = _at(data, where)
        payload = BYTE_PAYLOADS[what % len(BYTE_PAYLOADS)]
        if kind == "insert":
            data = data[:i] + payload + data[i:]
        elif kind == "replace":
            start, end = _token_span(data, i)
            data = data[:start] + payload + data[end:]
        elif kind == "delete":
            data = data[:i] + data[i + 1 + what % 64 :]
        elif kind == "flip" and i < len(data):
            data = data[:i] + bytes([data[i] ^ (1 << (what % 8))]) + data[i + 1 :]
        elif kind == "duplicate":
            line_start = data.rfind(b"\n", 0, i) + 1
            line_end = data.find(b"\n", i)
            line_end = len(data) if line_end < 0 else line_end + 1
            data = data[:line_end] + data[line_start:line_end] + data[line_end:]
        elif kind == "truncate":
            data = data[:i]
    return data


def mutate_json_rows(rows: list[dict[str, Any]], ops: Sequence[Op]) -> bytes:
    """Sets fields of JSON rows to payload values (``NaN`` written as the bare token)."""
    rows = [dict(r) for r in rows]
    for _, where, what in ops:
        row = rows[int(where * len(rows)) % len(rows)]
        keys = sorted(row)
        key = keys[(what // len(VALUE_PAYLOADS)) % len(keys)]
        row[key] = VALUE_PAYLOADS[what % len(VALUE_PAYLOADS)]
    return "".join(json.dumps(r) + "\n" for r in rows).encode("utf-8", "surrogatepass")


def store_rows(db_path: Path) -> dict[str, list[tuple[Any, ...]]]:
    """Every row of every table, to tell whether a refused import changed anything."""
    db = sqlite3.connect(db_path)
    try:
        tables = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")]
        return {t: db.execute(f"SELECT * FROM {t} ORDER BY rowid").fetchall() for t in tables}
    finally:
        db.close()


def check_outcome(call: Callable[[], Any]) -> str:
    """Runs a reader on a mutated file: it must succeed or raise one clean ``InputError``.

    Returns:
        ``ok`` or ``refused``.
    """
    try:
        call()
    except InputError as exc:
        message = str(exc)
        assert "\n" not in message and "\r" not in message, message
        assert "\x1b" not in message and "\x00" not in message, repr(message)
        assert len(message) < 2000, message[:200]
        return "refused"
    return "ok"
