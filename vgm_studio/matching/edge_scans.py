"""The scans behind edges: each edge's log opened once, with the options it was read with."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from vgm_studio.core.hashing import content_hash
from vgm_studio.datasets import ReadOptions, Scan, ScanLog, open_log
from vgm_studio.errors import InputError
from vgm_studio.matching.edges import Edge


class EdgeScans:
    """Finds the two scans of an edge, reading and caching each log once."""

    def __init__(self, search_dirs: tuple[Path, ...] = ()) -> None:
        self._logs: dict[tuple[str, str], ScanLog] = {}
        self._search_dirs = search_dirs

    def log_for(self, edge: Edge) -> ScanLog:
        key = (edge.log_path, edge.log_sha256)
        log = self._logs.get(key)
        if log is None:
            path = self._locate(edge)
            read = edge.params.get("read") or {}
            try:
                options = ReadOptions(**read)
            except TypeError as exc:
                raise InputError(
                    path, f"edge {edge.edge_id} has unknown read options: {exc}"
                ) from None
            # Hash before parsing: a path in an edges file must not make us read, and then
            # quote in an error, a file that is not the log the edge was made from.
            if edge.log_sha256 and content_hash(path) != edge.log_sha256:
                raise InputError(
                    path,
                    f"content differs from the log edge {edge.edge_id} was "
                    "made from (sha256 mismatch); make the candidates again",
                )
            log = open_log(path, options)
            self._logs[key] = log
        return log

    def _locate(self, edge: Edge) -> Path:
        path = Path(edge.log_path)
        # Only a regular file or a bag folder: never a device, a FIFO or a socket.
        if path.is_file() or path.is_dir():
            return path
        for folder in self._search_dirs:
            alt = folder / path.name
            if alt.is_file() or alt.is_dir():
                return alt
        raise InputError(path, f"log of edge {edge.edge_id} not found")

    def scans(self, edge: Edge) -> tuple[Scan, Scan]:
        log = self.log_for(edge)
        if not (0 <= edge.a < len(log) and 0 <= edge.b < len(log)):
            raise InputError(
                log.path,
                f"edge {edge.edge_id} names scans {edge.a}, {edge.b} but the log has {len(log)}",
            )
        return log.scans[edge.a], log.scans[edge.b]


def check_viewable(rows: Sequence[tuple[int, Edge]], source: Path) -> None:
    """Refuses edges the studio could not show, before any is stored.

    Each edge's log must be where the edge says, hold the content it was made from, and hold
    the scans it names. Each log is read once.

    Args:
        rows: (line, edge) pairs of the file the edges come from.
        source: That file, for the messages.

    Raises:
        InputError: ``source:line: field: what is wrong`` for the first edge that fails.
    """
    scans = EdgeScans()
    for line, edge in rows:
        if not edge.log_sha256:
            raise InputError(
                source,
                "log_sha256: missing; the studio reads only a log whose content it can check",
                line,
            )
        try:
            log = scans.log_for(edge)
        except InputError as exc:
            raise InputError(source, f"log_path: {exc}", line) from None
        for field, index in (("a", edge.a), ("b", edge.b)):
            if index >= len(log):
                raise InputError(
                    source,
                    f"{field}: scan {index} is past the end of its log ({len(log)} scans)",
                    line,
                )
