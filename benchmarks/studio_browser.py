"""Driving the studio as an annotator does: a real server process and a headless Chromium.

Shared by the tests and benchmarks, not part of the package: the browser tests, the latency and
trainer benchmarks use it. Needs Debian's
``chromium`` and Python's ``playwright`` (the test extras); nothing here downloads a browser.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

# Without the networking flags Chromium keeps calling home, and on closed networks those
# connections fail noisily; software WebGL is all a headless machine has.
CHROMIUM_ARGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)
# The position line and edge id: what changes when a tab shows another edge.
_SHOWN_JS = (
    "() => Array.from(document.querySelectorAll('strong, code')).map(e => e.innerText).join('|')"
)
_POSITION = re.compile(r"^(\d+) / (\d+)$")


def chromium_path() -> str | None:
    """The system Chromium, or None when it is not installed."""
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return "/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def studio_process(
    args: Sequence[str], port: int, timeout: float = 120.0, env: dict[str, str] | None = None
) -> Iterator[subprocess.Popen[str]]:
    """Runs ``vgm-studio ARGS --port PORT`` until it says it serves; kills it afterwards."""
    cmd = [sys.executable, "-m", "vgm_studio.tools.cmd", *args, "--port", str(port)]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **(env or {})},
    )
    try:
        deadline = time.monotonic() + timeout
        lines: list[str] = []
        assert proc.stdout is not None
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line and proc.poll() is not None:
                raise RuntimeError(f"studio exited with {proc.returncode}:\n{''.join(lines)}")
            lines.append(line)
            if line.startswith("VGM Studio:"):
                break
        else:
            raise TimeoutError("studio did not start:\n" + "".join(lines))
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=30)


class StudioPage:
    """One studio tab in a playwright page, with what an annotator reads and presses."""

    def __init__(self, page: Any, url: str, timeout: float = 30.0) -> None:
        self.page = page
        self.timeout_ms = timeout * 1000
        page.goto(url)
        self.wait_for(lambda: self.edge_id() is not None or self.empty())
        # Hotkeys go to the focused page: click the 3D view (by coordinates; see library notes).
        page.mouse.click(200, 200)

    def wait_for(self, condition: Any, timeout: float | None = None) -> None:
        deadline = time.monotonic() + (timeout or self.timeout_ms / 1000)
        while time.monotonic() < deadline:
            try:
                if condition():
                    return
            except Exception:  # the page is still building its panel
                pass
            time.sleep(0.005)
        raise TimeoutError("studio page did not reach the expected state")

    def _strong_texts(self) -> list[str]:
        return list(self.page.locator("strong").all_inner_texts())

    def position(self) -> tuple[int, int]:
        """(k, n) of ``k / n``: the tab's place in its queue."""
        for text in self._strong_texts():
            match = _POSITION.match(text.strip())
            if match:
                return int(match.group(1)), int(match.group(2))
        raise LookupError("no position shown")

    def edge_id(self) -> str | None:
        """The edge shown now (the id under the position line)."""
        codes = self.page.locator("code").all_inner_texts()
        return codes[0].strip() if codes else None

    def empty(self) -> bool:
        return bool(self.page.get_by_text("This queue is empty").count())

    def labelled(self) -> int:
        text = self.page.get_by_text(re.compile(r"labelled \d+ of")).first.inner_text()
        return int(re.search(r"labelled (\d+) of", text).group(1))  # type: ignore[union-attr]

    def trainer(self) -> str:
        """The trainer's lines in the panel ("" while the studio runs none)."""
        lines = self.page.locator("p").filter(has_text="Trainer:")
        return str(lines.first.inner_text()) if lines.count() else ""

    def _shown(self) -> str:
        return str(self.page.evaluate(_SHOWN_JS))

    def _wait_changed(self, before: str) -> None:
        # Polled inside the page at every animation frame: no round trip per check.
        self.page.wait_for_function(
            f"before => ({_SHOWN_JS})() !== before",
            arg=before,
            polling="raf",
            timeout=self.timeout_ms,
        )

    def press(self, key: str) -> float:
        """Presses a hotkey and waits until the tab shows another edge; returns the seconds."""
        before = self._shown()
        start = time.perf_counter()
        self.page.keyboard.press(key)
        self._wait_changed(before)
        return time.perf_counter() - start

    def click(self, button: str) -> float:
        """Clicks a panel button (``Success``, ``Undo``, …) and waits for the next edge."""
        before = self._shown()
        start = time.perf_counter()
        self.page.get_by_role("button", name=re.compile(f"^{button}")).click()
        self._wait_changed(before)
        return time.perf_counter() - start

    def choose_queue(self, name: str) -> None:
        """Picks a queue in the dropdown and waits for the tab to show it."""
        self.page.get_by_role("combobox", name="Queue").click()
        self.page.get_by_role("option", name=name).click()
        self.wait_for(
            lambda: name in self.page.locator("p").filter(has_text=" · ").first.inner_text()
        )
        self.page.mouse.click(200, 200)

    def screenshot(self, path: Path) -> None:
        # The browser's own "software WebGL" notice is not the studio's: close it first.
        closes = self.page.locator("button.mantine-Notification-closeButton").all()
        for close in closes:
            close.click()
        if closes:
            time.sleep(0.5)  # the notice slides away
        self.page.screenshot(path=str(path))


@contextmanager
def chromium(viewport: tuple[int, int] = (1400, 850)) -> Iterator[Any]:
    """A headless Debian Chromium under playwright; yields a browser context."""
    from playwright.sync_api import sync_playwright

    path = chromium_path()
    if path is None:
        raise FileNotFoundError("chromium is not installed (apt-get install chromium)")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=path, args=list(CHROMIUM_ARGS))
        try:
            context = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]})
            yield context
        finally:
            browser.close()
