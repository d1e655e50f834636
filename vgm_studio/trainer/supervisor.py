"""Keeps one trainer process alive beside the app: starts it, restarts it, stops it.

The app must outlive its trainer, so nothing here raises into the caller: a trainer that cannot
start or keeps dying is reported in the store (state ``crashed``) and in the trainer's log file,
and restarted after a growing pause. While another trainer runs on the store (a second studio
on the same workspace, or ``vgm-studio trainer`` alone) it starts none and crashes nothing: the
running trainer serves every studio of the store, and this one takes over when it ends.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from vgm_studio.labels.opening import open_store
from vgm_studio.trainer.lock import held_elsewhere

LOG_NAME = "trainer.log"


@dataclass(frozen=True)
class Backoff:
    """Pauses before restarts: ``first`` seconds, doubling up to ``longest``; a trainer that
    ran ``healthy`` seconds or more starts the count again."""

    first: float = 1.0
    longest: float = 60.0
    healthy: float = 60.0
    # How often to look again while another process's trainer runs.
    standby: float = 5.0

    def pause(self, failures: int) -> float:
        return float(min(self.first * 2 ** max(failures - 1, 0), self.longest))


class TrainerSupervisor:
    """Runs ``python -m vgm_studio.trainer`` for a workspace and restarts it when it dies.

    Args:
        workspace: The workspace folder (its store must exist).
        retrain_every: Passed to the trainer.
        base: Labelled edge files passed as ``--base``.
        from_scratch: Passed to the trainer.
        extra_args: More trainer options (``--epochs 4``, say).
        backoff: Pauses before restarts.

    Example:
        >>> supervisor = TrainerSupervisor(Path("ws"), retrain_every=25)
        >>> supervisor.start()
        >>> ...
        >>> supervisor.stop()
    """

    def __init__(
        self,
        workspace: Path,
        retrain_every: int = 25,
        base: Sequence[Path] = (),
        from_scratch: bool = False,
        extra_args: Sequence[str] = (),
        backoff: Backoff | None = None,
        url: str | None = None,
    ) -> None:
        self.workspace = Path(workspace)
        self.url = url
        self.backoff = backoff or Backoff()
        self.command = [
            sys.executable,
            "-m",
            "vgm_studio.trainer",
            "--workspace",
            str(self.workspace),
            "--retrain-every",
            str(retrain_every),
            "--parent-pid",
            str(os.getpid()),
            *[arg for path in base for arg in ("--base", str(path))],
            *(["--from-scratch"] if from_scratch else []),
            *(["--store", url] if url else []),
            *extra_args,
        ]
        self.restarts = 0
        # True while another process's trainer serves the store and this one waits.
        self.standing_by = False
        self._proc: subprocess.Popen[bytes] | None = None
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    @property
    def pid(self) -> int | None:
        """The trainer process's id while one runs."""
        proc = self._proc
        return proc.pid if proc is not None and proc.poll() is None else None

    @property
    def log_path(self) -> Path:
        return self.workspace / LOG_NAME

    def start(self) -> None:
        """Starts the trainer and its watchdog thread; returns at once."""
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                return
            self._stopping.clear()
            self._thread = threading.Thread(target=self._watch, daemon=True, name="trainer")
            self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Ends the trainer (SIGTERM, then SIGKILL after ``timeout`` seconds) and the watchdog."""
        self._stopping.set()
        try:
            proc = self._proc
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(5)
            if self._thread is not None:
                self._thread.join(timeout)
        except Exception as exc:  # stopping must not fail the app's shutdown
            self._note(f"supervisor: stopping the trainer failed ({exc})")

    def _watch(self) -> None:
        failures = 0
        while not self._stopping.is_set():
            if self._stand_by():
                continue
            started = time.monotonic()
            code = self._run_once()
            if self._stopping.is_set():
                break
            if code != 0 and held_elsewhere(self.workspace, self.url):
                continue  # another studio's trainer took the lock first: not a crash
            failures = 1 if time.monotonic() - started >= self.backoff.healthy else failures + 1
            pause = self.backoff.pause(failures)
            self._crashed(f"trainer exited with {code}; restarting in {pause:.1f} s")
            self._stopping.wait(pause)
            if not self._stopping.is_set():
                self.restarts += 1

    def _stand_by(self) -> bool:
        """Waits a while when another trainer serves the store; says whether it did."""
        elsewhere = held_elsewhere(self.workspace, self.url)
        if elsewhere != self.standing_by:
            self._note(
                "supervisor: another trainer runs on this store; using it"
                if elsewhere
                else "supervisor: no other trainer runs on this store; starting one"
            )
        self.standing_by = elsewhere
        if elsewhere:
            self._stopping.wait(self.backoff.standby)
        return elsewhere

    def _run_once(self) -> int | None:
        """Runs the trainer until it exits; returns its exit code (None: it never started)."""
        try:
            # A team store's models folder may not exist before its first version.
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            with self.log_path.open("ab") as log:
                proc = subprocess.Popen(
                    self.command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
                )
                self._proc = proc
                if self._stopping.is_set():  # stop() ran while we were starting it
                    proc.terminate()
                return proc.wait()
        except Exception as exc:  # cannot start (no disk space, fork failed): try again later
            self._note(f"supervisor: cannot start the trainer ({exc})")
            return None

    def _crashed(self, message: str) -> None:
        """Tells the app (through the store) that the trainer died; never raises."""
        self._note(f"supervisor: {message}")
        try:
            from vgm_studio.trainer.registry import read_state, report

            store = open_store(self.workspace, self.url, create=False)
            try:
                last = read_state(store)
                if last.get("state") == "crashed":  # the trainer said why: keep its words
                    reason = last.get("message", "").split("; trainer exited")[0]
                    message = f"{reason}; {message}" if reason else message
                report(store, "crashed", message=message)
            finally:
                store.close()
        except Exception:  # the store itself may be what is broken; the log has the line
            pass

    def _note(self, line: str) -> None:
        with contextlib.suppress(OSError), self.log_path.open("a") as log:
            log.write(line + "\n")
