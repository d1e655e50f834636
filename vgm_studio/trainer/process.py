"""The trainer as a process: ``python -m vgm_studio.trainer --workspace DIR``.

``vgm-studio trainer`` and the app's supervisor both end up in ``run_trainer``; this module's
``main`` is what the supervisor starts, without the rest of the command line.
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from vgm_studio.errors import InputError, exit_on_error
from vgm_studio.trainer.fit import FitConfig
from vgm_studio.trainer.promotion import PromotionRule
from vgm_studio.trainer.worker import Stop, TrainerConfig, Worker

PROG = "vgm-studio trainer"


def _to_stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def run_trainer(
    workspace: Path,
    config: TrainerConfig,
    parent_pid: int | None = None,
    say: Callable[[str], None] = _to_stderr,
    url: str | None = None,
) -> None:
    """Trains versions from a workspace's labels as they come in, until stopped.

    Ctrl-C, SIGTERM (the app's supervisor stopping it) and the app's death end it cleanly.

    Raises:
        InputError: A base file is missing, the workspace is not one, or another trainer runs.
    """
    for path in config.base:
        if not path.is_file():
            raise InputError(path, "no such edges file")
    worker = Worker(workspace, config, parent_pid=parent_pid, log=say, url=url)
    say(
        f"trainer: watching {url or workspace} (a version every {config.retrain_every} labels; "
        "Ctrl-C stops)"
    )
    _stop_on_sigterm()
    try:
        worker.run()
    except (KeyboardInterrupt, Stop, SystemExit):
        say("trainer: stopped")


def _stop_on_sigterm() -> None:
    """SIGTERM (the app's supervisor stopping us) ends the trainer like Ctrl-C: cleanly."""

    def handler(_signum: int, _frame: Any) -> None:
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, handler)


def _parser() -> argparse.ArgumentParser:
    fit = FitConfig()
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("--workspace", type=Path, required=True)
    parser.add_argument("--store", default=None)  # a team store; --workspace holds its models
    parser.add_argument("--retrain-every", type=int, default=TrainerConfig.retrain_every)
    parser.add_argument("--base", type=Path, action="append", default=[])
    parser.add_argument("--from-scratch", action="store_true")
    parser.add_argument("--epochs", type=int, default=fit.epochs)
    parser.add_argument("--epoch-size", type=int, default=fit.epoch_size)
    parser.add_argument("--min-held-out", type=int, default=PromotionRule.min_per_class)
    parser.add_argument("--parent-pid", type=int, default=None)
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    """The process's entry point: arguments in, ``run_trainer``, errors as one line."""
    args = _parser().parse_args(argv)
    config = TrainerConfig(
        retrain_every=args.retrain_every,
        base=tuple(args.base),
        from_scratch=args.from_scratch,
        fit=FitConfig(epochs=args.epochs, epoch_size=args.epoch_size),
        promotion=PromotionRule(min_per_class=args.min_held_out),
    )
    exit_on_error(
        PROG, lambda: run_trainer(args.workspace, config, args.parent_pid, url=args.store)
    )
