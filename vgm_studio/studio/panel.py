"""One browser tab's control panel: its handles, and the text it shows about an edge.

viser renders markdown with raw HTML and no sanitising, so every string that comes from a
file or a text box goes through ``plain`` (or ``code``) before it is put into markdown.
"""

from __future__ import annotations

import html
import math
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import viser

from vgm_studio.core import se2
from vgm_studio.labels.agreement import PairAgreement
from vgm_studio.matching.edges import Edge
from vgm_studio.studio.queues import Queue, is_conflict

if TYPE_CHECKING:  # the trainer (and torch) is imported only where a studio runs one
    from vgm_studio.trainer import TrainerStatus

# Keys under an annotator's left hand, so the right stays on the mouse.
HOTKEYS: dict[str, str] = {
    "success": "S",
    "failure": "F",
    "skip": "D",
    "undo": "Z",
    "previous": "Q",
    "next": "E",
    "guess": "G",
    "layers": "V",
    "reset_view": "R",
}
_TITLES = {"reset_view": "Reset view", "layers": "Points / VGM / both"}
# Markdown's own punctuation; < > & are left to html.escape, which turns them into entities
# (a backslash before "&" would show the entity's letters instead).
_MARKDOWN_PUNCTUATION = re.compile(r"([\\`*_{}\[\]()#+\-.!|~])")
_BLANK = np.full((8, 8, 3), 17, dtype=np.uint8)


def plain(text: object, limit: int = 300) -> str:
    """``text`` as markdown that shows it literally: no HTML, no markup, one line.

    Args:
        text: Anything from a file or a text box.
        limit: Characters kept; longer text ends in "…".
    """
    flat = " ".join(str(text).split())  # a newline would end a table row
    if len(flat) > limit:
        flat = flat[:limit] + "…"
    return html.escape(_MARKDOWN_PUNCTUATION.sub(r"\\\1", flat), quote=True)


def code(text: object) -> str:
    """A code span of ``text`` when that is safe (no backtick, one line), else ``plain``."""
    value = str(text)
    if "`" in value or "\n" in value or "\r" in value or len(value) > 100:
        return plain(value)
    return f"`{value}`"


@dataclass
class Panel:
    """The handles of one tab's panel (viser GUI elements, this client's only)."""

    position: viser.GuiMarkdownHandle
    agreement: viser.GuiMarkdownHandle  # the conflicts queue's header
    progress: Any  # viser does not export its progress bar handle's type
    facts: viser.GuiMarkdownHandle
    queue: viser.GuiDropdownHandle[Any]
    annotator: viser.GuiTextHandle
    note: viser.GuiTextHandle
    show_guess: viser.GuiCheckboxHandle
    trainer: viser.GuiMarkdownHandle
    layers: viser.GuiMarkdownHandle
    vgm: viser.GuiImageHandle
    minimap: viser.GuiImageHandle


def build_panel(
    client: viser.ClientHandle,
    annotator: str,
    queue: Queue,
    actions: dict[str, Callable[[], None]],
    queues: Sequence[Queue] = tuple(Queue),
) -> Panel:
    """Adds the panel to ``client``'s GUI and wires buttons and hotkeys to ``actions``.

    ``queues`` are those the dropdown offers (a run's queues only where edges carry a run).

    What an annotator presses and the trainer's state come first, so that at 1400×850 the
    buttons and *Train now* are in view without scrolling; pictures and settings follow.
    """
    gui = client.gui
    position = gui.add_markdown("**– / –**")
    agreement = gui.add_markdown("", visible=False)
    progress = gui.add_progress_bar(0.0, color="teal")
    for action, colour in (("success", "green"), ("failure", "red")):
        button = gui.add_button(
            f"{_title(action)} ({HOTKEYS[action]})",
            color=colour,  # type: ignore[arg-type]  # one of viser's colour names
        )
        button.on_click(_caller(actions, action))
    for row in (("skip", "undo"), ("previous", "next")):
        group = gui.add_button_group("", [f"{_title(a)} ({HOTKEYS[a]})" for a in row])
        group.on_click(_group_caller(actions, group, row))
    for action, key in HOTKEYS.items():
        command = gui.add_command(f"{_title(action)} ({key})", hotkey=key)  # type: ignore[arg-type]
        command.on_trigger(_caller(actions, action))
    trainer = gui.add_markdown("")
    train_now = gui.add_button("Train now", hint="Ask the background trainer for a new version.")
    train_now.on_click(_caller(actions, "train_now"))
    minimap = gui.add_image(_BLANK, format="png")
    facts = gui.add_markdown("")
    show_guess = gui.add_checkbox("Place by initial guess (G)", False)
    vgm = gui.add_image(_BLANK, format="png")
    layers = gui.add_markdown("")
    with gui.add_folder("Queue and annotator"):
        queue_dd = gui.add_dropdown("Queue", [q.value for q in queues], initial_value=queue.value)
        annotator_text = gui.add_text("Annotator", annotator)
        note = gui.add_text("Note", "", hint="Saved with the next label, then cleared.")
    return Panel(
        position,
        agreement,
        progress,
        facts,
        queue_dd,
        annotator_text,
        note,
        show_guess,
        trainer,
        layers,
        vgm,
        minimap,
    )


def _title(action: str) -> str:
    return _TITLES.get(action, action.capitalize())


def ask_training(client: viser.ClientHandle, train_now: Callable[[], None] | None) -> None:
    """The panel's "Train now": asks the trainer for a version, or says none runs."""
    if train_now is None:
        client.add_notification(
            "No trainer", "This studio runs without one.", auto_close_seconds=3.0
        )
        return
    train_now()
    client.add_notification(
        "Training asked for", "The trainer starts a new version.", auto_close_seconds=3.0
    )


def layers_text(layers: str) -> str:
    """The 3D view's legend and which layers show."""
    both = "in the same cell" if "raw" in layers else "within a beam spacing"
    return (
        f"<small>3D view: {layers} (V) · R resets the view. Points: blue previous scan, "
        "orange current scan, grey current scan at its reference pose. VGM cells: green "
        f"previous, magenta current, white both {both}.</small>"
    )


def _group_caller(
    actions: dict[str, Callable[[], None]], group: Any, row: tuple[str, ...]
) -> Callable[[Any], None]:
    """A button group's callback: runs the action of the button pressed."""
    by_label = {f"{_title(a)} ({HOTKEYS[a]})": a for a in row}

    def call(_event: Any) -> None:
        action = by_label.get(str(group.value))
        if action is not None:
            actions[action]()

    return call


def _caller(actions: dict[str, Callable[[], None]], action: str) -> Callable[[Any], None]:
    """A viser callback that runs ``actions[action]`` (looked up when fired, not now)."""

    def call(_event: Any) -> None:
        actions[action]()

    return call


def trainer_text(status: TrainerStatus) -> str:
    """The background trainer's state in two lines."""
    state: str = status.state
    if state == "training" and status.epochs:
        state = f"training, epoch {status.epoch} of {status.epochs}"
    if status.active_version is not None:
        active = f"v{status.active_version}"
    elif status.active_model is not None:  # a model not trained here, the bundled one say
        active = status.active_model.split(":")[0]
    else:
        active = "none yet"
    m = status.metrics
    figures = ""
    if m.get("accuracy") is not None:
        figures = " · held-out acc {:.2f}, F1 {:.2f}".format(m["accuracy"], m.get("f1") or 0.0)
    pending = " · Train now asked" if status.pending_request else ""
    text = (
        f"**Trainer:** {state}{pending}  \nmodel {active}{figures} · "
        f"{status.labels_since} labels since"
    )
    # The trainer's last words: why it waits, or why its last version was not promoted.
    if status.state != "training" and status.message and status.message != "watching the labels":
        text += f"  \n{status.message}"
    return text


def position_text(index: int, total: int, labelled: int, edges: int, queue: Queue) -> str:
    """``17 / 412`` in the queue, and the workspace's progress."""
    share = 100 * labelled / edges if edges else 0.0
    where = f"{index + 1} / {total}" if total else "0 / 0"
    return f"**{where}** · {queue.value}  \nlabelled {labelled} of {edges} edges ({share:.0f}%)"


def agreement_text(pairs: Iterable[PairAgreement], limit: int = 4) -> str:
    """The conflicts queue's header: Cohen's kappa and shared edges per pair of annotators."""
    lines = []
    for pair in list(pairs)[:limit]:
        kappa = "–" if pair.kappa is None else f"{pair.kappa:.2f}"
        lines.append(
            f"{plain(pair.first, 40)} · {plain(pair.second, 40)}: κ {kappa} on "
            f"{pair.shared} shared edges ({pair.agreed} agree)"
        )
    if not lines:
        return "**Agreement:** no edge has two annotators yet"
    return "**Agreement** (Cohen's κ)  \n" + "  \n".join(lines)


def facts_text(
    edge: Edge,
    votes: dict[str, str],
    p_success: float | None,
    threshold: float,
    use_guess: bool,
    notes: dict[str, str] | None = None,
    scoring: tuple[int, int] | None = None,
    run: Sequence[tuple[str, str]] = (),
) -> str:
    """The edge's facts as a markdown table: matcher figures, model, reference, labels.

    Every value read from the edge or the labels goes through ``plain``/``code``. While a
    model scores the edges, ``scoring`` is (done, total): an edge not scored yet says so.
    ``run`` are rows of a SLAM run's decisions (``decisions.decision_rows``, already safe),
    shown before the labels.
    """
    m = edge.match
    rows = [
        ("edge", code(edge.edge_id)),
        ("kind", f"{plain(edge.kind)}, scans {edge.a} → {edge.b}"),
    ]
    if isinstance(m.get("inlier_ratio"), (int, float)):
        rows.append(("inliers", f"{100 * m['inlier_ratio']:.0f}%"))
    if isinstance(m.get("residual"), (int, float)):
        rows.append(("residual", f"{1000 * m['residual']:.1f} mm"))
    if "iterations" in m:
        converged = plain(m.get("converged", "?"))
        rows.append(("iterations", f"{plain(m['iterations'])}, converged {converged}"))
    moved = se2.pose_error(edge.guess, edge.estimate)
    rows.append(("match moved guess", f"{100 * moved[0]:.1f} cm, {math.degrees(moved[1]):.1f}°"))
    if p_success is None and scoring is not None:
        rows.append(("p(success)", f"scoring {scoring[0]:,} / {scoring[1]:,}"))
    elif p_success is None:
        rows.append(("p(success)", "no model"))
    else:
        says = "success" if p_success >= threshold else "failure"
        rows.append(("p(success)", f"{p_success:.2f} (model: {says})"))
    if edge.reference is not None:
        pose = edge.guess if use_guess else edge.estimate
        exy, eth = se2.pose_error(edge.reference, pose)
        rows.append(
            (
                "reference",
                f"{plain(edge.label or 'no label')} "
                f"({100 * exy:.1f} cm, {math.degrees(eth):.1f}° off)",
            )
        )
    rows.extend(run)
    if votes:
        text = ", ".join(
            f"{plain(who, 60)}: {plain(label)}"
            + (f" ({plain(notes[who], 120)})" if notes and notes.get(who) else "")
            for who, label in sorted(votes.items())
        )
        if is_conflict(votes):
            text += " — **conflict**"
        rows.append(("labels", text))
    else:
        rows.append(("labels", "none yet"))
    drawn = "initial guess" if use_guess else "match estimate"
    table = "\n".join(f"| {k} | {v} |" for k, v in rows)
    return f"| placed by | {drawn} |\n|---|---|\n{table}"
