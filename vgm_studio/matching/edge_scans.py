"""The scans behind edges: each edge's log opened once, with the options it was read with."""

from __future__ import annotations

from pathlib import Path

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
            log = open_log(path, options)
            if edge.log_sha256 and log.content_hash != edge.log_sha256:
                raise InputError(
                    path,
                    f"content differs from the log edge {edge.edge_id} was "
                    "made from (sha256 mismatch); make the candidates again",
                )
            self._logs[key] = log
        return log

    def _locate(self, edge: Edge) -> Path:
        path = Path(edge.log_path)
        if path.exists():
            return path
        for folder in self._search_dirs:
            alt = folder / path.name
            if alt.exists():
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
