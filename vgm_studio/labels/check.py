"""The workspace check on open: a damaged label store stops a command before it serves or writes.

SQLite reports most damage only when a damaged page is read, which may be minutes into a
labeling session. ``PRAGMA quick_check`` reads every page once (milliseconds for a label
store), and the tables' columns are compared with the schema this version writes, so a
store that was edited or half-overwritten is refused with one line and a way out.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from vgm_studio.errors import InputError

# Shown with every "damaged" message: how to keep the labels that can still be read.
RECOVER = (
    "save what can be read with: sqlite3 {path} .recover | sqlite3 {folder}/recovered.sqlite, "
    "then move recovered.sqlite in place of {name} (or label in a fresh workspace)"
)


def expected_columns(schema_sql: str) -> dict[str, list[str]]:
    """Table → column names, as the schema the store is made with declares them."""
    memory = sqlite3.connect(":memory:")
    try:
        memory.executescript(schema_sql)
        tables = [r[0] for r in memory.execute("SELECT name FROM sqlite_master WHERE type='table'")]
        return {t: _columns(memory, t) for t in tables if not t.startswith("sqlite_")}
    finally:
        memory.close()


def _columns(db: sqlite3.Connection, table: str) -> list[str]:
    return [r[1] for r in db.execute(f"PRAGMA table_info({table})")]


def damaged(path: Path, what: str) -> InputError:
    """The one line for a damaged store: what is wrong and how to recover."""
    hint = RECOVER.format(path=path, folder=path.parent, name=path.name)
    return InputError(path, f"the label store is damaged ({what}); {hint}")


def check_workspace(db: sqlite3.Connection, path: Path, schema_sql: str) -> None:
    """Checks the store's pages and tables.

    Args:
        db: The open store.
        path: Its file, for the message.
        schema_sql: The ``CREATE TABLE`` statements the store is made with.

    Raises:
        InputError: A page is damaged, or a table or column of the schema is missing.
    """
    try:
        problems = [r[0] for r in db.execute("PRAGMA quick_check(3)").fetchall()]
        if problems != ["ok"]:
            raise damaged(path, "; ".join(str(p)[:120] for p in problems))
        for table, columns in expected_columns(schema_sql).items():
            found = _columns(db, table)
            missing = [c for c in columns if c not in found]
            if not found:
                raise damaged(path, f"table {table} is missing")
            if missing:
                raise damaged(path, f"table {table} lacks {', '.join(missing)}")
    except sqlite3.DatabaseError as exc:
        raise damaged(path, str(exc)) from None


def check_writable(db: sqlite3.Connection, path: Path) -> None:
    """Fails now, not at the first label, when the store cannot be written.

    SQLite opens a file it may not write (read-only, immutable) read-only without a word;
    a write that changes nothing, rolled back, finds out.

    Raises:
        InputError: The store or its folder is read-only or immutable.
    """
    try:
        db.execute("BEGIN IMMEDIATE")
        try:
            db.execute("UPDATE meta SET value = value WHERE key = 'format'")
        finally:
            db.execute("ROLLBACK")
    except sqlite3.OperationalError as exc:
        if "locked" in str(exc) or "busy" in str(exc):
            return  # another process is writing: the store is writable
        raise InputError(
            path,
            f"the label store cannot be written ({exc}); make the workspace folder and its "
            "files writable (not read-only or immutable), or copy the workspace elsewhere",
        ) from None
