"""MkDocs hook: links in files included from the repository root, made to work in the site.

``docs/benchmarks.md`` includes ``BENCHMARKS.md`` with pymdownx.snippets. That file's links
are written relative to the repository root, as GitHub shows it (``docs/check-your-slam.md``,
``docs/images/trainer-curves.png``), while in the site they sit in ``docs/``. On a page that
includes a snippet, a relative link or picture that names no file next to the page but one
relative to the repository root is pointed at that file in ``docs/``; a link to a file
outside ``docs/`` (README.md, a script) keeps its text and loses the link. This runs before
MkDocs checks the page's links, so ``mkdocs build --strict`` still checks every link.
"""

from __future__ import annotations

import posixpath
import xml.etree.ElementTree as etree
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from markdown import Extension, Markdown
from markdown.treeprocessors import Treeprocessor
from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import Files
from mkdocs.structure.pages import Page

REPO = Path(__file__).resolve().parents[2]
# The pictures' old folder, which repository-root files may still name.
MOVED = {"assets/readme/": "docs/images/"}
SNIPPET = "--8<--"


class _State:
    """The page being rendered: MkDocs renders one page at a time, right after
    ``on_page_markdown`` has seen it."""

    page: str | None = None  # its path under docs/, when it includes a snippet
    docs: Path = REPO / "docs"


def _repo_target(path: str) -> str | None:
    """A root-relative link's file, as a path under the repository root; None if none."""
    for old, new in MOVED.items():
        if path.startswith(old) and (REPO / new / path[len(old) :]).is_file():
            path = new + path[len(old) :]
    return path if (REPO / path).is_file() else None


class _RepoLinks(Treeprocessor):
    def run(self, root: etree.Element) -> None:
        if _State.page is None:
            return
        page_dir = posixpath.dirname(_State.page)
        docs = _State.docs.resolve().relative_to(REPO).as_posix()
        for element in root.iter():
            key = {"a": "href", "img": "src"}.get(element.tag)
            url = element.get(key) if key else None
            if key is None or not url:
                continue
            parts = urlsplit(url)
            if parts.scheme or parts.netloc or not parts.path or url.startswith("/"):
                continue
            if (_State.docs / page_dir / parts.path).exists():
                continue  # already right for the site
            target = _repo_target(parts.path)
            if target is None:
                continue  # MkDocs reports it
            if target.startswith(docs + "/"):
                inside = target[len(docs) + 1 :]
                new = posixpath.relpath(inside, page_dir or ".")
                element.set(key, new + (f"#{parts.fragment}" if parts.fragment else ""))
            elif element.tag == "a":
                # The text stays, the link goes.
                element.tag = "span"
                element.attrib.pop("href")


class _RepoLinksExtension(Extension):
    def extendMarkdown(self, md: Markdown) -> None:
        # Above MkDocs's own link check ("relpath", priority 0), so it sees the new links.
        md.treeprocessors.register(_RepoLinks(md), "repo_links", 5)


def on_config(config: MkDocsConfig) -> MkDocsConfig:
    _State.docs = Path(config.docs_dir)
    config.markdown_extensions.append(_RepoLinksExtension())  # type: ignore[arg-type]
    return config


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    _State.page = page.file.src_uri if SNIPPET in markdown else None
    return markdown


def on_post_build(**_: Any) -> None:
    _State.page = None
