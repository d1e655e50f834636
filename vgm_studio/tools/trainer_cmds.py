"""``vgm-studio trainer`` and ``vgm-studio models``: the background trainer and its versions."""

from __future__ import annotations

import math
import os
import shutil
import signal
import tempfile
from pathlib import Path
from typing import Annotated, Any

import typer

from vgm_studio.errors import InputError

WorkspaceOpt = Annotated[Path, typer.Option(metavar="DIR", help="Workspace folder (label store).")]


def _stop_on_sigterm() -> None:
    """SIGTERM (the app's supervisor stopping us) ends the trainer like Ctrl-C: cleanly."""

    def handler(_signum: int, _frame: Any) -> None:
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, handler)


def trainer(
    workspace: WorkspaceOpt,
    retrain_every: Annotated[
        int, typer.Option(min=1, help="Train after this many new labels.")
    ] = 25,
    base: Annotated[
        list[Path] | None,
        typer.Option(metavar="EDGES.jsonl", help="Labelled edges to train on too (repeatable)."),
    ] = None,
    from_scratch: Annotated[
        bool, typer.Option(help="Start every version from fresh weights, not the active one.")
    ] = False,
    epochs: Annotated[int, typer.Option(min=1, help="Epochs at most per version.")] = 12,
    epoch_size: Annotated[int, typer.Option(min=1, help="Class-balanced draws per epoch.")] = 1024,
    parent_pid: Annotated[int | None, typer.Option(hidden=True)] = None,
) -> None:
    """Train model versions from a workspace's labels as they come in (runs until Ctrl-C)."""
    from vgm_studio.trainer.fit import FitConfig
    from vgm_studio.trainer.worker import Stop, TrainerConfig, Worker

    for path in base or []:
        if not path.is_file():
            raise InputError(path, "no such edges file")
    config = TrainerConfig(
        retrain_every=retrain_every,
        base=tuple(base or ()),
        from_scratch=from_scratch,
        fit=FitConfig(epochs=epochs, epoch_size=epoch_size),
    )
    worker = Worker(workspace, config, parent_pid=parent_pid, log=lambda s: typer.echo(s, err=True))
    typer.echo(
        f"trainer: watching {workspace} (a version every {retrain_every} labels; Ctrl-C stops)",
        err=True,
    )
    _stop_on_sigterm()
    try:
        worker.run()
    except (KeyboardInterrupt, Stop, SystemExit):
        typer.echo("trainer: stopped", err=True)


def _figure(metrics: dict[str, Any], key: str) -> str:
    value = metrics.get(key)
    if not isinstance(value, int | float) or not math.isfinite(value):
        return "–"
    return f"{value:.3f}"


def models_table(records: list[Any]) -> str:
    """The versions as a Markdown-like table: held-out figures, labels, time, promotion."""
    header = [
        "version",
        "created (UTC)",
        "labels",
        "held out",
        "accuracy",
        "F1",
        "AUC",
        "cut",
        "seconds",
        "status",
    ]
    rows = []
    for m in records:
        held = m.metrics.get("counts", {}).get("held_out", {})
        status = "active" if m.active else ("promoted" if m.promoted else "not promoted")
        rows.append(
            [
                m.name,
                m.created_at[:19].replace("T", " "),
                str(m.labels_seen),
                str(sum(held.values())) if held else "0",
                _figure(m.metrics, "accuracy"),
                _figure(m.metrics, "f1"),
                _figure(m.metrics, "auc"),
                _figure(m.metrics, "threshold"),
                f"{m.seconds:.0f}",
                status,
            ]
        )
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = [
        "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
        for r in [header, *rows]
    ]
    return "\n".join(lines)


def models(
    workspace: WorkspaceOpt,
    export: Annotated[
        int | None, typer.Option(metavar="N", min=1, help="Write version vN out as a checkpoint.")
    ] = None,
    out: Annotated[
        Path | None, typer.Option(metavar="FILE.pt", help="Where --export writes.")
    ] = None,
) -> None:
    """List a workspace's model versions and their held-out figures, or export one."""
    from vgm_studio.labels.store import LabelStore
    from vgm_studio.model.checkpoint import load_checkpoint
    from vgm_studio.trainer import registry

    if (export is None) != (out is None):
        raise InputError(None, "--export N and --out FILE.pt go together")
    store = LabelStore(workspace, create=False)
    try:
        records = registry.list_models(store)
        if export is None:
            if not records:
                typer.echo(f"{workspace}: no model versions yet (run vgm-studio trainer)")
                return
            typer.echo(models_table(records))
            return
        assert out is not None
        if out.suffix != ".pt":
            raise InputError(out, "the checkpoint must end in .pt")
        record = next((m for m in records if m.version == export), None)
        if record is None:
            known = ", ".join(m.name for m in records) or "none"
            raise InputError(workspace, f"no version v{export} (versions: {known})")
        load_checkpoint(record.path)  # refuses a damaged file rather than copying it
        _copy_atomically(record.path, out)
        typer.echo(f"wrote v{export} to {out}")
    finally:
        store.close()


def _copy_atomically(source: Path, out: Path) -> None:
    """Copies to a temporary file beside ``out``, then renames: ``out`` is whole or untouched."""
    if out.is_dir():
        raise InputError(out, "is a folder; give a file name to write")
    tmp: str | None = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent)
        os.close(fd)
        shutil.copyfile(source, tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, out)
    except OSError as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        raise InputError(out, f"cannot write here ({exc.strerror or exc})") from None
