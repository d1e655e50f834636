"""Errors that reach the user as one line: ``file:line: what is wrong``."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path


class InputError(Exception):
    """Bad input a user can fix: a missing file, a malformed line, an unknown option.

    The command line prints ``str(error)`` and exits with ``exit_code``, never a traceback.
    Most commands exit 1; ``compare`` exits 2, as its CI callers keep 1 for a failed rule.
    """

    def __init__(
        self,
        path: str | Path | None,
        message: str,
        line: int | None = None,
        exit_code: int = 1,
    ) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.message = message
        self.exit_code = exit_code
        super().__init__(str(self))

    def __str__(self) -> str:
        where = self.path or ""
        if self.line is not None:
            where = f"{where}:{self.line}"
        return f"{where}: {self.message}" if where else self.message


def require_utf8_path(path: str | Path) -> None:
    """Refuses a path that is not UTF-8 text (a stray byte from another system's encoding).

    Such a path cannot be written into an edges file, the label store or a message intact.

    Raises:
        InputError: Naming the path with the stray bytes shown as escapes.
    """
    text = str(path)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        shown = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        raise InputError(shown, "the path is not UTF-8 text; rename it") from None


def exit_on_error(prog: str, body: Callable[[], object]) -> None:
    """Runs a process's body; an expected error ends it with one line and an exit code.

    The one place where errors become exit codes, for ``vgm-studio`` and for the trainer's
    process alike: ``InputError`` exits 1, or its ``exit_code`` (``prog: error: file:line:
    what``), Ctrl-C 130, a
    reader that closed the pipe 0. Anything else is a bug and keeps its traceback.
    """
    try:
        body()
    except InputError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        sys.exit(130)
    except BrokenPipeError:
        sys.exit(0)
