"""Progress of long loops, on stderr: a bar on a terminal, plain lines everywhere else.

Every loop of the package that shows progress goes through ``track`` (an iterable) or
``counter`` (a count updated by hand). On a terminal that is a tqdm bar. Without one (CI,
``nohup``, a pipe, a log file) a bar would either be switched off, leaving minutes of
silence, or fill the file with carriage returns; so there a line such as

    matching: 4,200/15,630 edges (27%) 41 s, about 111 s left

is printed at most every ``VGM_PROGRESS_SECONDS`` seconds (10 by default), and one more when
the loop ends.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sized
from typing import Any, Generic, TextIO, TypeVar

from tqdm import tqdm

T = TypeVar("T")

# Seconds between two plain lines; the environment may ask for others (a CI log that wants
# fewer, a test that wants them now).
DEFAULT_EVERY = 10.0
EVERY_VARIABLE = "VGM_PROGRESS_SECONDS"


def _every() -> float:
    try:
        seconds = float(os.environ.get(EVERY_VARIABLE, DEFAULT_EVERY))
    except ValueError:
        return DEFAULT_EVERY
    return seconds if math.isfinite(seconds) and seconds >= 0 else DEFAULT_EVERY


def _is_terminal(stream: TextIO | None) -> bool:
    try:
        return stream is not None and stream.isatty()
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def _plural(unit: str) -> str:
    return unit + ("es" if unit.endswith(("s", "sh", "ch", "x")) else "s")


def _duration(seconds: float) -> str:
    if seconds < 100:
        return f"{seconds:.0f} s"
    minutes, rest = divmod(round(seconds), 60)
    return f"{minutes} min {rest:02d} s"


class Progress(Generic[T]):
    """A loop's progress: a tqdm bar on a terminal, plain lines elsewhere, or nothing.

    Use ``track`` and ``counter`` to make one. It iterates what it tracks, and takes
    ``update``, ``set_postfix``, ``set_description`` and ``close`` as a tqdm bar does.
    """

    def __init__(
        self,
        iterable: Iterable[T] | None,
        *,
        desc: str,
        unit: str,
        total: int | None,
        enabled: bool = True,
        leave: bool = True,
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._iterable = iterable
        if total is None and isinstance(iterable, Sized):
            total = len(iterable)
        self.total = total
        self.desc, self.unit, self.leave = desc, unit, leave
        self.n = 0
        self._postfix = ""
        self._stream = stream
        self._clock = clock
        self._bar: Any = None
        self._plain = False
        self._closed = not enabled
        if enabled:
            shown_on = stream if stream is not None else sys.stderr
            if _is_terminal(shown_on):
                self._bar = tqdm(
                    total=total, desc=desc, unit=unit, leave=leave, file=shown_on, disable=False
                )
            else:
                self._plain = True
        self._start = self._last = clock()
        self._every = _every()

    def __iter__(self) -> Iterator[T]:
        if self._iterable is None:
            raise TypeError("this progress counts by hand (counter): it has nothing to iterate")
        for item in self._iterable:
            yield item
            self.update()
        self.close()

    def __enter__(self) -> Progress[T]:
        return self

    def __exit__(self, kind: type[BaseException] | None, *_: object) -> None:
        if kind is None:
            self.close()
        elif self._bar is not None:  # a failed loop leaves no line saying it finished
            self._bar.close()

    def update(self, n: int = 1) -> None:
        """Counts ``n`` more done; a plain line when the last is ``every`` seconds old."""
        self.n += n
        if self._bar is not None:
            self._bar.update(n)
        elif self._plain and self._clock() - self._last >= self._every:
            self._say()

    def set_postfix(self, **values: object) -> None:
        """Figures shown after the count (``loops=12, kept=10``)."""
        self._postfix = ", ".join(f"{k} {v}" for k, v in values.items())
        if self._bar is not None:
            self._bar.set_postfix(values)

    def set_total(self, total: int) -> None:
        """The count now known to be the whole (it was not when the loop began)."""
        self.total = total
        if self._bar is not None:
            self._bar.total = total
            self._bar.refresh()

    def set_description(self, desc: str) -> None:
        self.desc = desc
        if self._bar is not None:
            self._bar.set_description(desc)

    def close(self) -> None:
        """Ends the loop: the bar closes, or the last plain line is printed (once)."""
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()
        elif self._plain and self.leave:
            self._say()

    def line(self) -> str:
        """The plain line for where the loop is now."""
        elapsed = self._clock() - self._start
        if self.total:
            share = self.n / self.total
            text = f"{self.desc}: {self.n:,}/{self.total:,} {_plural(self.unit)} ({share:.0%})"
            text += f" {_duration(elapsed)}"
            if 0 < self.n < self.total:
                text += f", about {_duration(elapsed * (self.total - self.n) / self.n)} left"
        else:
            text = f"{self.desc}: {self.n:,} {_plural(self.unit)} {_duration(elapsed)}"
        return f"{text}, {self._postfix}" if self._postfix else text

    def _say(self) -> None:
        stream = self._stream if self._stream is not None else sys.stderr
        print(self.line(), file=stream, flush=True)
        self._last = self._clock()


def track(
    iterable: Iterable[T],
    desc: str,
    unit: str,
    *,
    total: int | None = None,
    enabled: bool = True,
    leave: bool = True,
) -> Progress[T]:
    """``iterable``, with its progress shown (see the module docstring).

    Args:
        iterable: What the loop runs over.
        desc: What the loop does, first on the line (``matching``).
        unit: What one item is (``edge``).
        total: Items in all, when ``iterable`` has no length.
        enabled: False shows nothing (the caller's ``progress`` flag).
        leave: False: a terminal bar goes when done, and no plain line closes the loop
            (an inner loop whose caller reports each round).
    """
    return Progress(iterable, desc=desc, unit=unit, total=total, enabled=enabled, leave=leave)


def counter(
    total: int | None, desc: str, unit: str, *, enabled: bool = True, leave: bool = True
) -> Progress[None]:
    """A progress counted by hand with ``update`` (see ``track`` for the arguments)."""
    return Progress(None, desc=desc, unit=unit, total=total, enabled=enabled, leave=leave)
