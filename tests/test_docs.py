"""The shell examples of README.md and of the documentation site (docs/, built by MkDocs) hold.

Every ``vgm-studio`` command in a ```bash block (and in a workflow's ``run:`` step of a
```yaml block) names a command the CLI has and options that command accepts; every benchmark
script, test file and pip extra an example names exists, with the options it is given. The
examples that need only what the repository bundles (the demo log under ``datasets/``, the
models under ``assets/models/``) and the files earlier examples of the same page wrote are run
as written, in a scratch folder: each exits as its page says and writes the files its options
name. A renamed option or file breaks a test here, not a reader's first try.

Also here: no text file of the repository numbers the sittings the project was worked in.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import posixpath
import re
import shutil
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.doc_examples import (
    CLI,
    REPO,
    SHELLS,
    WRITES,
    Block,
    Example,
    checker,
    doc_pages,
    examples,
    fenced_blocks,
    parse_call,
)

# Commands that serve until Ctrl-C or need a Ray cluster: their examples are parsed, never run.
NEVER_RUN = frozenset({"demo", "label", "trainer", "fleet"})
# Options that name a server (a PostgreSQL store, a Ray head) the tests do not have.
NEEDS_A_SERVER = frozenset({"--store", "--ray-address"})
# What the repository bundles, and examples may read as they are.
BUNDLED = ("datasets", "assets")
# One example may take this long; the demo log's slowest takes about 20 s on two cores.
TIMEOUT_S = 300
FILE_NAME = re.compile(r"\.[A-Za-z][A-Za-z0-9]*$")
# A page's sample output that shows a rule failing: the command before it exits 1.
RULE_FAILS = re.compile(r"\bFAILS\b")
WORK_NUMBER = re.compile(r"\bsessions?\s*\d", re.IGNORECASE)


# --- the commands of every page, checked ---------------------------------------------------


CHECKED = [
    ex
    for page in doc_pages()
    for ex in examples(page)
    if ex.error or any(map(checker, ex.commands))
]


@pytest.mark.parametrize("example", [pytest.param(ex, id=ex.where) for ex in CHECKED])
def test_example_names_commands_options_and_files_that_exist(example: Example):
    """Each documented command line holds as written: a ``vgm-studio`` command the CLI has,
    with options it accepts and as many arguments as it takes; benchmark scripts and test
    files that exist, given options their ``--help`` lists; pip extras pyproject.toml
    declares."""
    problems = [example.error] if example.error else []
    problems += [p for words in example.commands if (check := checker(words)) for p in check()]
    assert problems == [], f"{example.where}: {example.text}"


# --- the examples that run on what the repository bundles --------------------------------


@dataclass
class Step:
    """One runnable command of a page: what it reads and writes, what it waits for (the
    earlier steps of its page that touch its files) and the exit status its page states."""

    example: Example
    words: tuple[str, ...]
    reads: tuple[str, ...]
    writes: tuple[str, ...]
    after: tuple[int, ...]
    expected: int = 0


def _norm(path: str) -> str:
    return posixpath.normpath(path)


def _within(path: str, folder: str) -> bool:
    """True when ``path`` is ``folder`` or lies in it."""
    path, folder = _norm(path), _norm(folder)
    return path == folder or path.startswith(folder + "/")


def _bundled(path: str) -> bool:
    return _norm(path).split("/")[0] in BUNDLED and (REPO / path).exists()


def _names_a_file(value: str) -> bool:
    return "://" not in value and ("/" in value or bool(FILE_NAME.search(value)))


def _shows_failure(block: Block) -> bool:
    """True when the page's sample output right after ``block`` shows a rule failing."""
    later = [b for b in fenced_blocks(block.page) if b.start > block.end]
    if not later or later[0].lang not in ("text", ""):
        return False
    return bool(RULE_FAILS.search("\n".join(line for _, line in later[0].lines)))


def _step(example: Example, words: tuple[str, ...], steps: list[Step]) -> Step | None:
    """``words`` as a step of its page, or None when it cannot run here."""
    if posixpath.basename(words[0]) != CLI or any("$" in w for w in words):
        return None
    call = parse_call(words)
    names = {name for name, _ in call.options}
    if call.problems or not call.sub or call.sub in NEVER_RUN or names & NEEDS_A_SERVER:
        return None
    if "--help" in names:
        return None
    reads = list(call.arguments)
    writes = []
    for name, value in call.options:
        if value and name in WRITES and name != "--workspace":
            writes.append(value)
        elif value and (name == "--workspace" or _names_a_file(value)):
            reads.append(value)
    if any(p.startswith(("/", "~")) or _norm(p).startswith("..") for p in reads + writes):
        return None
    written = [w for s in steps for w in s.writes]
    if not all(_bundled(p) or any(_within(p, w) for w in written) for p in reads):
        return None
    touched = reads + writes
    after = tuple(
        i
        for i, s in enumerate(steps)
        if any(_within(w, p) or _within(p, w) for w in s.writes for p in touched)
        or any(_within(r, w) or _within(w, r) for r in s.reads for w in writes)
    )
    return Step(example, words, tuple(reads), tuple(writes), after)


@functools.cache
def run_plan(page: str) -> tuple[Step, ...]:
    """The commands of ``page`` that run on what the repository bundles, in page order: each
    ``vgm-studio`` command (not one that serves, nor one that needs a server) whose inputs are
    bundled files or files an earlier runnable command of the page writes. The last of a
    block exits 1 where the page's sample output after the block shows a rule failing."""
    steps: list[Step] = []
    for example in examples(page):
        if example.block.lang in SHELLS:
            for words in example.commands:
                step = _step(example, words, steps)
                if step is not None:
                    steps.append(step)
    for block in {s.example.block for s in steps}:
        if _shows_failure(block):
            [s for s in steps if s.example.block == block][-1].expected = 1
    return tuple(steps)


@dataclass
class Outcome:
    """How one step ran: in which folder, its exit status and output, or why it did not."""

    cwd: Path
    returncode: int | None = None
    stdout: str = ""
    stderr: str = ""
    seconds: float = 0.0
    not_run: str = ""


def _cli_command() -> list[str]:
    path = os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])
    exe = shutil.which(CLI, path=path)
    return [exe] if exe else [sys.executable, "-m", "vgm_studio.tools.cmd"]


def _execute(words: tuple[str, ...], cwd: Path) -> Outcome:
    start = time.monotonic()
    try:
        proc = subprocess.run(
            [*_cli_command(), *words[1:]],
            cwd=cwd,
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
            check=False,
        )
    except subprocess.TimeoutExpired:
        return Outcome(cwd, seconds=TIMEOUT_S, not_run=f"still running after {TIMEOUT_S} s")
    return Outcome(cwd, proc.returncode, proc.stdout, proc.stderr, time.monotonic() - start)


def _copy_bundled(plan: tuple[Step, ...], cwd: Path) -> None:
    for path in {p for step in plan for p in step.reads if _bundled(p)}:
        source, target = REPO / path, cwd / path
        if target.exists():
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        if source.is_dir():
            shutil.copytree(source, target)
        else:
            shutil.copy2(source, target)


def _digest(path: Path) -> str:
    """The bytes of a file, or of every file in a folder, as one hash."""
    digest = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for file in files:
        digest.update(file.relative_to(path).as_posix().encode() if path.is_dir() else b"")
        digest.update(file.read_bytes() if file.exists() else b"missing")
    return digest.hexdigest()


def _copy_written(step: Step, source: Path, target: Path) -> None:
    for name in step.writes:
        if (source / name).is_dir():
            shutil.copytree(source / name, target / name, dirs_exist_ok=True)
        elif (source / name).exists():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source / name, target / name)


def run_pages(root: Path) -> dict[tuple[str, int], Outcome]:
    """Runs every page's plan, each page in a folder of its own under ``root`` holding copies
    of the bundled files it reads. Pages run side by side, as many commands at once as the
    machine has cores (at most 4); a step starts when the steps it waits for have ended, and
    does not run when one of them failed. A command line run already on inputs of the same
    bytes (pages repeat an example) runs once: the repeat gets its outcome and a copy of
    the files it wrote, kept aside as they were when it ended."""
    slots = threading.BoundedSemaphore(max(1, min(os.cpu_count() or 1, 4)))
    outcomes: dict[tuple[str, int], Outcome] = {}
    ended: dict[tuple[str, int], threading.Event] = {}
    first_runs: dict[tuple[object, ...], tuple[str, int]] = {}
    kept: dict[tuple[str, int], Path] = {}
    lock = threading.Lock()
    every = Counter(step.words for page in doc_pages() for step in run_plan(page))
    repeated = {words for words, count in every.items() if count > 1}

    def outcome_of(page: str, index: int, cwd: Path) -> Outcome:
        plan = run_plan(page)
        step = plan[index]
        for i in step.after:
            ended[(page, i)].wait()
        failed = [plan[i] for i in step.after if not _passed(plan[i], outcomes[(page, i)])]
        if failed:
            return Outcome(cwd, not_run=f"not run: line {failed[0].example.line} failed")
        key = (step.words, *(_digest(cwd / p) for p in step.reads))
        with lock:
            first = first_runs.setdefault(key, (page, index))
        if first != (page, index):
            ended[first].wait()
            if first in kept:
                _copy_written(step, kept[first], cwd)
            return dataclasses.replace(outcomes[first], cwd=cwd)
        with slots:
            outcome = _execute(step.words, cwd)
        if step.words in repeated:
            kept[(page, index)] = root / ".kept" / f"{page.replace('/', '-')}-{index}"
            _copy_written(step, cwd, kept[(page, index)])
        return outcome

    def work(page: str, index: int, cwd: Path) -> None:
        outcome = Outcome(cwd, not_run="not run: the test's runner failed")
        try:
            outcome = outcome_of(page, index, cwd)
        finally:
            outcomes[(page, index)] = outcome
            ended[(page, index)].set()

    threads = []
    for page in doc_pages():
        plan = run_plan(page)
        if not plan:
            continue
        cwd = root / page.replace("/", "-")
        cwd.mkdir()
        _copy_bundled(plan, cwd)
        for index in range(len(plan)):
            ended[(page, index)] = threading.Event()
            threads.append(threading.Thread(target=work, args=(page, index, cwd)))
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return outcomes


def _passed(step: Step, outcome: Outcome) -> bool:
    return not outcome.not_run and outcome.returncode == step.expected


def _empty(path: Path) -> bool:
    if path.is_dir():
        return not any(p.is_file() and p.stat().st_size > 0 for p in path.rglob("*"))
    return path.stat().st_size == 0


RUNNABLE = [
    pytest.param(page, line, id=f"{page}:{line}")
    for page in doc_pages()
    for line in sorted({step.example.line for step in run_plan(page)})
]


@pytest.fixture(scope="module")
def page_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, int], Outcome]:
    """Every page's runnable examples, run once."""
    return run_pages(tmp_path_factory.mktemp("docs-examples"))


def test_the_core_workflows_are_run_not_only_parsed():
    """The pages' examples of a SLAM run, an audit of its graph and a comparison of two runs
    need only the demo log, so they run here, not only their options checked."""
    ran = {parse_call(step.words).sub for page in doc_pages() for step in run_plan(page)}
    assert {"slam", "audit", "compare"} <= ran


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.parametrize(("page", "line"), RUNNABLE)
def test_bundled_example_runs_as_written(page_runs, page: str, line: int):
    """An example that needs only the bundled log and model (and what the page's earlier
    examples wrote) runs as written: it exits as the page says (0, or 1 where the page's
    sample output shows a rule failing), without a traceback, and every file or folder its
    writing options name is there and not empty."""
    for index, step in enumerate(run_plan(page)):
        if step.example.line != line:
            continue
        outcome = page_runs[(page, index)]
        where = f"{page}:{line}: {' '.join(step.words)}"
        assert not outcome.not_run, f"{where}\n{outcome.not_run}"
        output = (
            f"{where}\n--- stdout\n{outcome.stdout[-3000:]}\n--- stderr\n{outcome.stderr[-3000:]}"
        )
        assert outcome.returncode == step.expected, (
            f"exit {outcome.returncode}, the page says {step.expected}: {output}"
        )
        assert "Traceback" not in outcome.stderr, output
        missing = [
            w for w in step.writes if not (outcome.cwd / w).exists() or _empty(outcome.cwd / w)
        ]
        assert missing == [], f"{where}: not written or empty: {missing}"


# --- what the repository's files say ------------------------------------------------------


def _repository_files() -> list[str]:
    """The files git holds or would add (tracked, or new and not ignored)."""
    proc = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=REPO,
        capture_output=True,
        check=True,
    )
    return sorted({name for name in proc.stdout.decode().split("\0") if name})


def _text(path: Path) -> str | None:
    """The file's text, or None for a binary file (or one that is gone)."""
    try:
        data = path.read_bytes()
    except (FileNotFoundError, IsADirectoryError):
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


@pytest.mark.skipif(
    shutil.which("git") is None or not REPO.joinpath(".git").exists(), reason="not a git checkout"
)
def test_no_file_numbers_the_sittings_the_project_was_worked_in():
    """No text file of the repository (tracked, or new and not ignored) matches
    ``WORK_NUMBER``: a figure or a decision cites its date and commit, not the numbered
    sitting of the work it came from."""
    found = []
    for name in _repository_files():
        text = _text(REPO / name)
        if text is None:
            continue
        for match in WORK_NUMBER.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            found.append(f"{name}:{line}: {match[0]!r}")
    assert found == []
