"""A fleet manifest: the logs of a fleet run, one JSON object per line.

JSONL because every line stands alone: a manifest grows by appending, a bad line is named
by its number, and it needs nothing beyond the standard library. Each line is::

    {"log": "robot7/2026-11-30.clf", "reference": "robot7/2026-11-30.gfs.log",
     "relations": "robot7/2026-11-30.relations", "name": "robot7-monday"}

``log`` is required; ``reference`` (a corrected log or a log with TRUEPOS: labels the
candidates and gives SLAM its reference poses), ``relations`` (a Freiburg relations file:
scores SLAM by relation errors) and ``name`` (the log's row and folder; default the log's
file name) are optional. Relative paths are read from the manifest's folder. Blank lines and
lines starting with ``#`` are skipped.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vgm_studio.errors import InputError

_FIELDS = ("log", "reference", "relations", "name")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


@dataclass(frozen=True)
class ManifestEntry:
    """One log of a fleet.

    Attributes:
        name: Names the log's row and its output folder; unique in the manifest.
        log: The log.
        reference: A corrected log or a log with TRUEPOS, if any.
        relations: A Freiburg relations file, if any.
        line: The manifest line it came from.
    """

    name: str
    log: Path
    reference: Path | None = None
    relations: Path | None = None
    line: int = 0


def read_manifest(path: Path) -> list[ManifestEntry]:
    """Reads and checks a manifest: every bad line is reported, one line each.

    Raises:
        InputError: The manifest cannot be read, lists no log, or has bad lines (all of
            them named in the message, ``manifest:line: what is wrong`` each).
    """
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read the manifest ({exc})") from None
    entries: list[ManifestEntry] = []
    errors: list[str] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip() or raw.lstrip().startswith("#"):
            continue
        try:
            entries.append(_entry(path, number, raw))
        except InputError as exc:
            errors.append(str(exc))
    seen: dict[str, int] = {}
    for e in entries:
        if e.name in seen:
            errors.append(
                f"{path}:{e.line}: name {e.name!r} is taken by line {seen[e.name]}; "
                'give one of them a "name"'
            )
        seen.setdefault(e.name, e.line)
    if errors:
        # The first error is the exception's own; the others follow on their own lines.
        raise InputError(None, "\n".join(sorted(errors, key=_line_of)))
    if not entries:
        raise InputError(path, 'lists no log (one JSON object per line, {"log": "PATH"})')
    return entries


def _line_of(error: str) -> int:
    match = re.search(r":(\d+): ", error)
    return int(match.group(1)) if match else 0


def _entry(manifest: Path, number: int, raw: str) -> ManifestEntry:
    try:
        doc: Any = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise InputError(manifest, f"not JSON ({exc.msg})", number) from None
    if not isinstance(doc, dict):
        raise InputError(manifest, 'not a JSON object such as {"log": "PATH"}', number)
    unknown = sorted(set(doc) - set(_FIELDS))
    if unknown:
        raise InputError(
            manifest, f"unknown field(s) {', '.join(unknown)} (known: {', '.join(_FIELDS)})", number
        )
    if "log" not in doc:
        raise InputError(manifest, 'no "log" field', number)
    for key in _FIELDS:
        if key in doc and (not isinstance(doc[key], str) or not doc[key].strip()):
            raise InputError(manifest, f'"{key}" must be a non-empty string', number)
    paths = {
        k: _path(manifest, number, k, doc[k]) for k in ("log", "reference", "relations") if k in doc
    }
    name = doc.get("name", paths["log"].name)
    if not _NAME.match(name):
        raise InputError(
            manifest,
            f"name {name!r} must be letters, digits, '.', '_' or '-' (it names a folder); "
            'give a "name"',
            number,
        )
    return ManifestEntry(name, paths["log"], paths.get("reference"), paths.get("relations"), number)


def _path(manifest: Path, number: int, key: str, value: str) -> Path:
    path = Path(value).expanduser()
    if not path.is_absolute():
        path = manifest.parent / path
    if not path.exists():
        raise InputError(manifest, f'"{key}": no such file {value!r}', number)
    return path
