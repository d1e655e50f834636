"""Opening a label store where the user pointed: a workspace folder (SQLite) or a team
database (``postgresql://USER@HOST[:PORT]/DB``) with a folder for its model files."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from vgm_studio.errors import InputError
from vgm_studio.labels.store import LabelStore


def is_store_url(location: str | Path | None) -> bool:
    """Whether ``location`` names a PostgreSQL store rather than a workspace folder."""
    return isinstance(location, str) and location.startswith(("postgresql://", "postgres://"))


def open_store(
    workspace: Path, url: str | None = None, *, create: bool = True, durable: bool = True
) -> LabelStore:
    """The store at ``url`` (models under ``workspace``), or the workspace folder's own.

    Args:
        workspace: The workspace folder; with ``url``, the folder for model files.
        url: A PostgreSQL URL, or None for the workspace's SQLite store.
        create: Make a missing workspace (a team database is made when empty, always).
        durable: SQLite only: flush every commit (PostgreSQL's commits always are).

    Raises:
        InputError: Not a store URL, no server, or a store of another version.
    """
    if url is None:
        return LabelStore(workspace, create=create, durable=durable)
    if not is_store_url(url):
        raise InputError(None, f"--store {url}: not a postgresql://USER@HOST[:PORT]/DB URL")
    from vgm_studio.labels.postgres import PgLabelStore  # psycopg only for team stores

    return PgLabelStore(url, models_dir=workspace)


def store_url(store: LabelStore) -> str | None:
    """The team database's URL of an open store; None for a workspace's SQLite store."""
    url = getattr(store, "url", None)
    return url if isinstance(url, str) else None


@contextmanager
def store_to_fill(workspace: Path, url: str | None = None) -> Iterator[LabelStore]:
    """The store a command is about to fill, made when missing; gone again if the command fails.

    A command that makes a workspace and then fails on its input (a log it cannot read, a
    bad export) must not leave the empty folder behind: the next command would take it for
    the user's workspace. Only what this call made is removed (the workspace folder and the
    parent folders made for it); a workspace that was there before is kept as it is, and a
    team database is never dropped. The store stays open when the body succeeds.

    Args:
        workspace: The workspace folder; with ``url``, the folder for model files.
        url: A PostgreSQL URL, or None for the workspace's SQLite store.

    Raises:
        InputError: As ``open_store``; and whatever the body raises, after the clean-up.
    """
    made = None if url is not None else _first_missing(workspace)
    store = open_store(workspace, url)
    try:
        yield store
    except BaseException:  # Ctrl-C included: an interrupted first fill leaves no workspace
        if made is not None:
            store.close()
            shutil.rmtree(made, ignore_errors=True)
        raise


def _first_missing(folder: Path) -> Path | None:
    """The outermost folder of ``folder``'s path that does not exist yet (None: all do)."""
    missing = None
    folder = folder.absolute()
    for path in (folder, *folder.parents):
        if path.exists():
            break
        missing = path
    return missing
