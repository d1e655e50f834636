"""Opening a label store where the user pointed: a workspace folder (SQLite) or a team
database (``postgresql://USER@HOST[:PORT]/DB``) with a folder for its model files."""

from __future__ import annotations

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
