"""MkDocs hook: the command reference page, ``reference/cli.md``, made from the CLI itself.

On every build (``mkdocs build`` and each rebuild of ``mkdocs serve``) the typer app of
``vgm_studio.tools.cmd`` is turned into its command group (``typer.main.get_command``), and
each command's usage, help and parameters are written as a page: what ``vgm-studio COMMAND
--help`` prints, in tables. Typer carries its own copy of click, so the group is walked through
typer's ``Context`` and the commands' own methods, never ``import click``. The
page is added to the build as a generated file, never written into ``docs/``, so it cannot
go stale and is not committed.
"""

from __future__ import annotations

import html
import re
import sys
from pathlib import Path
from typing import Any

import typer
from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files

PAGE = "reference/cli.md"
REPO = Path(__file__).resolve().parents[2]
# The trailing "  [default: …; x>=1]" or "  [required]" click appends to an option's help.
_EXTRA = re.compile(r"\s{2}\[([^\[\]]*)\]$")
# Markdown's own punctuation in help text: shown as written, never as markup.
_MARKDOWN = re.compile(r"([\\`*_\[\]])")


def _text(value: str) -> str:
    """Help text as markdown that shows it literally, on one line, fit for a table cell."""
    flat = " ".join(value.split())
    escaped = _MARKDOWN.sub(r"\\\1", html.escape(flat, quote=False))
    return escaped.replace("|", "&#124;")


def _code(value: str) -> str:
    """An option's names and metavar as a code span a table cell holds (pipes included)."""
    return f"<code>{html.escape(value, quote=False).replace('|', '&#124;')}</code>"


def _paragraphs(help_text: str | None) -> list[str]:
    """A command's help, one markdown paragraph per paragraph of its docstring."""
    blocks = re.split(r"\n\s*\n", (help_text or "").strip())
    return [_text(block) for block in blocks if block.strip()]


def _rows(command: Any, ctx: typer.Context, arguments: bool) -> list[str]:
    """Table rows of the command's arguments (or options), as ``--help`` lists them."""
    rows = []
    for param in command.get_params(ctx):
        if (param.param_type_name == "argument") != arguments:
            continue
        record = param.get_help_record(ctx)
        if record is None:  # hidden
            continue
        names, help_text = record
        match = _EXTRA.search(help_text)
        extra = match.group(1) if match else ""
        meaning = help_text[: match.start()] if match else help_text
        rows.append(f"| {_code(names)} | {_text(meaning)} | {_text(extra)} |")
    return rows


def _table(title: str, rows: list[str]) -> list[str]:
    if not rows:
        return []
    return [f"| {title} | what it does | default, range |", "|---|---|---|", *rows, ""]


def _command_section(name: str, command: Any, root: typer.Context) -> list[str]:
    ctx = typer.Context(command, info_name=name, parent=root)
    lines = [
        f"## `{root.info_name} {name}` {{ #{name} }}",
        "",
        "```text",
        ctx.get_usage(),
        "```",
        "",
    ]
    for paragraph in _paragraphs(command.help):
        lines += [paragraph, ""]
    lines += _table("argument", _rows(command, ctx, arguments=True))
    lines += _table("option", _rows(command, ctx, arguments=False))
    return lines


def _app() -> Any:
    """The CLI's command group, importable from a checkout that is not installed too."""
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    from vgm_studio.tools.cmd import app

    return typer.main.get_command(app)


def reference_page() -> str:
    """The whole page, in the order ``vgm-studio --help`` lists the commands."""
    from vgm_studio.tools.cmd import PROG

    group = _app()
    root = typer.Context(group, info_name=PROG)
    names = group.list_commands(root)
    commands = {name: group.get_command(root, name) for name in names}
    lines = [
        "# Command reference",
        "",
        "<!-- Made at build time by docs/hooks/cli_reference.py from the command line itself: "
        "change the commands' help in vgm_studio/tools/, not this page. -->",
        "",
        f"Every command of `{PROG}`, with the usage, help and options its `--help` prints "
        "(this page is made from the command line at each build, so it says what the "
        "installed version does). Every command also takes `--help`; "
        f"`{PROG} --version` prints the version.",
        "",
        "| command | what it does |",
        "|---|---|",
    ]
    for name, command in commands.items():
        assert command is not None
        summary = command.get_short_help_str(limit=120)
        lines.append(f"| [`{name}`](#{name}) | {_text(summary)} |")
    lines += ["", f"Options of `{PROG}` itself:", ""]
    lines += _table("option", _rows(group, root, arguments=False))
    for name, command in commands.items():
        assert command is not None
        lines += _command_section(name, command, root)
    return "\n".join(lines) + "\n"


def on_files(files: Files, config: MkDocsConfig) -> Files:
    """Adds the generated page (in place of any file of that name in docs/)."""
    existing = files.get_file_from_path(PAGE)
    if existing is not None:
        files.remove(existing)
    files.append(File.generated(config, PAGE, content=reference_page()))
    return files
