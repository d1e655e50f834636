"""``python -m vgm_studio.trainer --workspace DIR``: the trainer process the app supervises.

The same command as ``vgm-studio trainer``, without the rest of the command line.
"""

from __future__ import annotations

import sys

import typer

from vgm_studio.errors import InputError
from vgm_studio.tools import trainer_cmds


def main(argv: list[str] | None = None) -> None:
    app = typer.Typer(add_completion=False, pretty_exceptions_enable=False, rich_markup_mode=None)
    app.command()(trainer_cmds.trainer)
    try:
        typer.main.get_command(app).main(
            args=argv, prog_name="vgm-studio trainer", standalone_mode=False
        )
    except InputError as exc:
        typer.echo(f"vgm-studio trainer: error: {exc}", err=True)
        sys.exit(1)
    except typer.Abort:
        sys.exit(130)
    except typer.TyperException as exc:  # a usage error
        typer.echo(f"vgm-studio trainer: error: {exc}", err=True)
        sys.exit(2)


if __name__ == "__main__":
    main()
