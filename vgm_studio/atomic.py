"""Files written whole or not at all: a temporary file beside the target, then a rename.

A reader (another process, the studio, a resumed run) sees the old file or the new one, never
half of one, whether the writer raises, is killed or the disk fills. A power cut is another
matter: nothing here waits for the disk (no fsync), which the files written often (resume
states every epoch, a fleet's rows) would pay for each time. The trainer's model versions,
which the label store's rows name, do wait (``trainer.fit.write_checkpoint``).
"""

from __future__ import annotations

import errno
import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


def _read_umask() -> int:
    # os.umask can only be read by setting it; done once, at import, before any thread writes.
    mask = os.umask(0)
    os.umask(mask)
    return mask


_FILE_MODE = 0o666 & ~_read_umask()


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yields a temporary path beside ``path`` to write; on a clean exit it becomes ``path``.

    The temporary file exists (empty) when the block starts, lives in the same folder (so the
    rename is atomic) and is named uniquely, so two writers of one target never share it. Its
    name ends in random characters, not ``path``'s suffix, so a scan for ``*.pt`` or
    ``*.jsonl`` never takes a half-written file for a whole one. On an exception it is
    removed and ``path`` is untouched. The result gets the mode a plainly created file would
    (``0o666`` less the umask), not ``mkstemp``'s private ``0o600``.

    Args:
        path: The file to write. Missing parent folders are created.

    Raises:
        OSError: The folder cannot be made or written (``NotADirectoryError`` naming the
            file that stands where a folder should), or the rename fails (``path`` is a
            folder).

    Example:
        >>> with atomic_path(out / "table.parquet") as tmp:  # doctest: +SKIP
        ...     pq.write_table(table, tmp)
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        # mkdir's "File exists" for a parent that is a file reads as if the target were.
        blocker = file_in_the_way(path.parent)
        if blocker is None:
            raise
        text = f"{blocker} is a file, not a folder"
        raise NotADirectoryError(errno.ENOTDIR, text, str(blocker)) from None
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def file_in_the_way(folder: Path) -> Path | None:
    """The file that stands where ``folder`` or one of the folders above it should be; None
    where there is none (the folder can then be made, permissions allowing)."""
    return next((p for p in (folder, *folder.parents) if p.exists() and not p.is_dir()), None)


def write_json_atomically(path: str | Path, doc: dict[str, Any]) -> None:
    """Writes ``doc`` as indented JSON to ``path`` whole or not at all (see ``atomic_path``)."""
    write_text_atomically(path, json.dumps(doc, indent=2) + "\n")


def write_text_atomically(path: str | Path, text: str, newline: str | None = None) -> None:
    """Writes ``text`` as UTF-8 to ``path`` whole or not at all (see ``atomic_path``).

    Args:
        path: The file to write.
        text: Its content.
        newline: As ``open``'s: ``""`` writes line ends as they are in ``text`` (CSV's CRLF).
    """
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline=newline) as f:
        f.write(text)
