"""The shell examples of README.md and the documentation site: the pages, their fenced blocks,
the commands in them, and what each command names (``tests/test_docs.py`` checks and runs
them; ``tests/test_repo_files.py`` reads what they write)."""

from __future__ import annotations

import functools
import posixpath
import re
import shlex
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")

REPO = Path(__file__).resolve().parents[1]
CLI = "vgm-studio"

# Options whose value is a file or folder the command writes (--workspace: label's and
# import's store, read by every other command).
WRITES = (
    "--out",
    "--map-png",
    "--record",
    "--json",
    "--png",
    "--workspace",
    "--markdown",
    "--g2o",
    "--trajectory",
    "--ros-map",
    "--edges-out",
    "--loops-out",
)

SHELLS = frozenset({"bash", "sh", "shell", "console"})
FENCE = re.compile(r"^(?P<indent>\s*)(?P<fence>`{3,}|~{3,})\s*(?P<lang>[\w+-]*)")
SUBSTITUTION = re.compile(r"\$\(([^()]*)\)")
SHELL_WORDS = frozenset({"if", "then", "else", "elif", "do", "while", "until", "!", "time"})
ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")


# --- the pages and their examples --------------------------------------------------------


def doc_pages() -> list[str]:
    """README.md, every page of the docs site, and the files a page includes whole."""
    docs = REPO / "docs"
    pages = ["README.md"]
    pages += sorted(
        p.relative_to(REPO).as_posix()
        for p in docs.rglob("*.md")
        if "hooks" not in p.relative_to(docs).parts  # the build's own code, not pages
    )
    for page in list(pages):
        # pymdownx.snippets: a line ``--8<-- "FILE"`` includes FILE (relative to the root).
        for name in re.findall(r'^--8<-- "([^"]+)"', (REPO / page).read_text(), re.MULTILINE):
            if (REPO / name).is_file() and name not in pages:
                pages.append(name)
    return pages


@dataclass(frozen=True)
class Block:
    """One fenced block of a page: its language, fence lines and numbered body lines."""

    page: str
    lang: str
    start: int
    end: int
    lines: tuple[tuple[int, str], ...]


@functools.cache
def fenced_blocks(page: str) -> tuple[Block, ...]:
    """Every fenced block of ``page`` in order, with its body's line numbers."""
    blocks = []
    opened: tuple[re.Match[str], int] | None = None
    body: list[tuple[int, str]] = []
    for number, line in enumerate((REPO / page).read_text().splitlines(), 1):
        match = FENCE.match(line)
        if opened is None:
            if match:
                opened, body = (match, number), []
            continue
        fence, start = opened
        if (
            match
            and not match["lang"]
            and match["fence"][0] == fence["fence"][0]
            and len(match["fence"]) >= len(fence["fence"])
        ):
            lang = fence["lang"].lower()
            blocks.append(Block(page, lang, start, number, tuple(body)))
            opened = None
            continue
        indent = len(fence["indent"])
        body.append((number, line.lstrip() if line[:indent].strip() else line[indent:]))
    return tuple(blocks)


def bash_text(page: str) -> str:
    """The text of ``page``'s shell blocks, one after the other."""
    return "\n".join(
        "\n".join(line for _, line in b.lines) for b in fenced_blocks(page) if b.lang in SHELLS
    )


def _drop_comment(line: str) -> str:
    """``line`` without its comment: a ``#`` that starts a word outside quotes."""
    quote = ""
    for i, char in enumerate(line):
        if quote:
            quote = "" if char == quote else quote
        elif char in "'\"":
            quote = char
        elif char == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i]
    return line


def _joined_lines(lines: tuple[tuple[int, str], ...]) -> list[tuple[int, str]]:
    """Lines as the shell reads them: comments dropped, ``\\`` continuations joined; each with
    the number of the line it starts on."""
    out: list[tuple[int, str]] = []
    pending, start = "", 0
    for number, raw in lines:
        line = _drop_comment(raw).rstrip()
        if not pending:
            start = number
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        pending = (pending + line).strip()
        if pending:
            out.append((start, pending))
        pending = ""
    if pending.strip():
        out.append((start, pending.strip()))
    return out


def _workflow_run_lines(block: Block) -> tuple[tuple[int, str], ...]:
    """The shell lines of a workflow's ``run:`` steps (GitHub Actions YAML)."""
    out: list[tuple[int, str]] = []
    lines = block.lines
    for i, (number, line) in enumerate(lines):
        match = re.match(r"^(\s*)(?:-\s+)?run:\s*(.*)$", line)
        if not match:
            continue
        value = match[2].strip()
        if value and value[0] not in "|>":
            out.append((number, value))
            continue
        indent = len(match[1])
        for later, text in lines[i + 1 :]:
            if text.strip() and len(text) - len(text.lstrip()) <= indent:
                break
            out.append((later, text.strip()))
    return tuple(out)


def simple_commands(line: str) -> list[list[str]]:
    """The simple commands of one shell line: split on ``&&``, ``||``, ``;``, ``|`` and ``&``,
    redirections dropped, leading ``VAR=value`` assignments and shell keywords dropped, and
    each ``$(...)`` substitution's commands added (the substitution itself stands as one
    ``$`` word)."""
    commands = [c for m in SUBSTITUTION.finditer(line) for c in simple_commands(m[1])]
    lexer = shlex.shlex(
        SUBSTITUTION.sub("$SUBSTITUTED", line), posix=True, punctuation_chars=";&|<>"
    )
    lexer.whitespace_split = True
    lexer.commenters = ""
    current: list[str] = []
    words = iter(list(lexer))
    for word in words:
        if word and set(word) <= set(";&|"):
            commands.append(current)
            current = []
        elif word and set(word) <= set("<>&"):
            next(words, None)  # a redirection's target
        else:
            current.append(word)
    commands.append(current)
    out = []
    for command in commands:
        while command and (command[0] in SHELL_WORDS or ASSIGNMENT.match(command[0])):
            command = command[1:]
        if command:
            out.append(command)
    return out


@dataclass(frozen=True)
class Example:
    """One line of a page's shell example: where it is, as written, and its commands."""

    page: str
    line: int
    text: str
    block: Block
    commands: tuple[tuple[str, ...], ...]
    error: str = ""  # why the shell could not read it

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"


@functools.cache
def examples(page: str) -> tuple[Example, ...]:
    """Every shell line of ``page``: the lines of its shell blocks and of its workflows'
    ``run:`` steps."""
    out = []
    for block in fenced_blocks(page):
        if block.lang in SHELLS:
            lines = block.lines
        elif block.lang in ("yaml", "yml"):
            lines = _workflow_run_lines(block)
        else:
            continue
        for number, text in _joined_lines(lines):
            try:
                commands = tuple(tuple(c) for c in simple_commands(text))
            except ValueError as exc:  # an unclosed quote
                out.append(Example(page, number, text, block, (), f"not shell: {exc}"))
                continue
            out.append(Example(page, number, text, block, commands))
    return tuple(out)


# --- what the command line accepts --------------------------------------------------------


@dataclass(frozen=True)
class Signature:
    """A sub-command's options (name → whether it takes a value) and positional arguments."""

    options: dict[str, bool]
    arguments: int  # at most; -1: any number
    required: int


@functools.cache
def cli_signatures() -> dict[str, Signature]:
    """Each ``vgm-studio`` sub-command's signature, read from the typer app itself; the key
    ``""`` holds the root's own options."""
    import typer

    from vgm_studio.tools.cmd import app

    root = typer.main.get_command(app)

    def signature(command: Any) -> Signature:
        options = {"--help": False}
        arguments = required = 0
        for param in command.params:
            if param.param_type_name == "argument":
                arguments = -1 if param.nargs < 0 or arguments < 0 else arguments + param.nargs
                required += max(param.nargs, 1) if param.required else 0
                continue
            takes_value = not (getattr(param, "is_flag", False) or getattr(param, "count", False))
            options.update(dict.fromkeys(param.opts, takes_value))
            options.update(dict.fromkeys(param.secondary_opts, False))
        return Signature(options, arguments, required)

    signatures = {name: signature(command) for name, command in root.commands.items()}
    signatures[""] = signature(root)
    return signatures


@dataclass(frozen=True)
class Call:
    """A ``vgm-studio`` command line taken apart as the CLI takes it."""

    sub: str
    options: tuple[tuple[str, str], ...]  # (name, value; "" for a flag)
    arguments: tuple[str, ...]
    problems: tuple[str, ...]


def parse_call(words: tuple[str, ...]) -> Call:
    """``words`` (``vgm-studio SUB ...``) parsed against the CLI's own signatures."""
    signatures = cli_signatures()
    rest = list(words[1:])
    sub = "" if not rest or rest[0].startswith("-") else rest.pop(0)
    if sub not in signatures:
        return Call(sub, (), (), (f"{CLI} has no command {sub!r}",))
    signature = signatures[sub]
    named = f"{CLI} {sub}".rstrip()
    problems: list[str] = []
    options: list[tuple[str, str]] = []
    arguments: list[str] = []
    remaining = iter(rest)
    for word in remaining:
        if word == "--":
            arguments += list(remaining)
        elif word.startswith("-") and word != "-" and not re.match(r"^-[\d.]", word):
            name, eq, value = word.partition("=")
            if name not in signature.options:
                problems.append(f"{named} has no option {name}")
            elif signature.options[name]:
                value = value if eq else next(remaining, "")
                problems += [] if value else [f"{named} {name} needs a value"]
                options.append((name, value))
            else:
                options.append((name, ""))
        else:
            arguments.append(word)
    if "--help" not in dict(options):
        if 0 <= signature.arguments < len(arguments):
            problems.append(f"{named} takes {signature.arguments} arguments, given {arguments}")
        if len(arguments) < signature.required:
            problems.append(f"{named} needs {signature.required} arguments, given {arguments}")
    return Call(sub, tuple(options), tuple(arguments), tuple(problems))


@functools.cache
def _help_options(*command: str) -> frozenset[str] | str:
    """The options ``command --help`` lists, or why it could not say."""
    proc = subprocess.run(
        [*command, "--help"], cwd=REPO, capture_output=True, text=True, timeout=120, check=False
    )
    if proc.returncode != 0:
        return f"`{' '.join(command)} --help` exited {proc.returncode}: {proc.stderr[-500:]}"
    return frozenset(re.findall(r"(?<![\w-])(--?[A-Za-z][\w-]*)", proc.stdout))


def _unknown_options(args: list[str], command: tuple[str, ...], what: str) -> list[str]:
    used = [a.partition("=")[0] for a in args if re.match(r"^--?[A-Za-z]", a)]
    if not used:
        return []
    known = _help_options(*command)
    if isinstance(known, str):
        return [known]
    return [f"{what} has no option {o}" for o in used if o not in known]


def _script_problems(script: str, args: list[str]) -> list[str]:
    if not (REPO / script).is_file():
        return [f"there is no script {script}"]
    return _unknown_options(args, (sys.executable, script), script)


def _pytest_problems(args: list[str]) -> list[str]:
    missing = [
        f"there is no test file {a}"
        for a in args
        if not a.startswith("-")
        and ("/" in a or a.split("::")[0].endswith(".py"))
        and not (REPO / a.split("::")[0]).exists()
    ]
    return missing + _unknown_options(args, (sys.executable, "-m", "pytest"), "pytest")


def _pip_problems(args: list[str]) -> list[str]:
    if not args or args[0] != "install":
        return []
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    ours = (".", "./", project["name"], project["name"].replace("-", "_"))
    extras = project.get("optional-dependencies", {})
    problems = []
    for word in args[1:]:
        match = re.fullmatch(r"(.+?)\[([^\]]*)\]", word)
        if not match or match[1] not in ours:
            continue
        for extra in filter(None, (e.strip() for e in match[2].split(","))):
            if extra not in extras:
                problems.append(f"pyproject.toml declares no extra {extra!r} ({word})")
    return problems


def checker(words: tuple[str, ...]) -> Callable[[], list[str]] | None:
    """What checks one documented command (it returns what is wrong), or None for a program
    these tests do not know (ssh, rerun, mkdocs, ...)."""
    program = posixpath.basename(words[0])
    args = list(words[1:])
    if program == CLI:
        return lambda: list(parse_call(words).problems)
    if program in ("pip", "pip3"):
        return lambda: _pip_problems(args)
    if program == "pytest":
        return lambda: _pytest_problems(args)
    if program in ("python", "python3") and args:
        if args[:2] == ["-m", "pytest"]:
            return lambda: _pytest_problems(args[2:])
        if args[:2] == ["-m", "pip"]:
            return lambda: _pip_problems(args[2:])
        if args[0].endswith(".py"):
            return lambda: _script_problems(args[0], args[1:])
    return None
