"""One browser tab's control panel: its handles, and the text it shows about an edge."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import viser

from vgm_studio.core import se2
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
}


@dataclass
class Panel:
    """The handles of one tab's panel (viser GUI elements, this client's only)."""

    position: viser.GuiMarkdownHandle
    progress: Any  # viser does not export its progress bar handle's type
    facts: viser.GuiMarkdownHandle
    queue: viser.GuiDropdownHandle[Any]
    annotator: viser.GuiTextHandle
    note: viser.GuiTextHandle
    show_guess: viser.GuiCheckboxHandle
    trainer: viser.GuiMarkdownHandle


def build_panel(
    client: viser.ClientHandle,
    annotator: str,
    queue: Queue,
    actions: dict[str, Callable[[], None]],
) -> Panel:
    """Adds the panel to ``client``'s GUI and wires buttons and hotkeys to ``actions``."""
    gui = client.gui
    position = gui.add_markdown("**– / –**")
    progress = gui.add_progress_bar(0.0, color="teal")
    colours = {"success": "green", "failure": "red"}
    for action in ("success", "failure", "skip", "previous", "undo", "next"):
        button = gui.add_button(
            f"{action.capitalize()} ({HOTKEYS[action]})",
            color=colours.get(action),  # type: ignore[arg-type]
        )
        button.on_click(_caller(actions, action))
    for action, key in HOTKEYS.items():
        command = gui.add_command(f"{action.capitalize()} ({key})", hotkey=key)  # type: ignore[arg-type]
        command.on_trigger(_caller(actions, action))
    show_guess = gui.add_checkbox("Place by initial guess (G)", False)
    facts = gui.add_markdown("")
    with gui.add_folder("Queue and annotator"):
        queue_dd = gui.add_dropdown("Queue", [q.value for q in Queue], initial_value=queue.value)
        annotator_text = gui.add_text("Annotator", annotator)
        note = gui.add_text("Note", "", hint="Saved with the next label, then cleared.")
    gui.add_markdown(
        "<small>blue: previous scan · orange: current scan · grey: current scan at its "
        "reference pose · under them, the two VGM channels</small>"
    )
    trainer = gui.add_markdown("")
    train_now = gui.add_button("Train now", hint="Ask the background trainer for a new version.")
    train_now.on_click(_caller(actions, "train_now"))
    return Panel(position, progress, facts, queue_dd, annotator_text, note, show_guess, trainer)


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


def facts_text(
    edge: Edge,
    votes: dict[str, str],
    p_success: float | None,
    threshold: float,
    use_guess: bool,
) -> str:
    """The edge's facts as a markdown table: matcher figures, model, reference, labels."""
    m = edge.match
    rows = [("edge", f"`{edge.edge_id}`"), ("kind", f"{edge.kind}, scans {edge.a} → {edge.b}")]
    if isinstance(m.get("inlier_ratio"), (int, float)):
        rows.append(("inliers", f"{100 * m['inlier_ratio']:.0f}%"))
    if isinstance(m.get("residual"), (int, float)):
        rows.append(("residual", f"{1000 * m['residual']:.1f} mm"))
    if "iterations" in m:
        rows.append(("iterations", f"{m['iterations']}, converged {m.get('converged', '?')}"))
    moved = se2.pose_error(edge.guess, edge.estimate)
    rows.append(("match moved guess", f"{100 * moved[0]:.1f} cm, {math.degrees(moved[1]):.1f}°"))
    if p_success is None:
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
                f"{edge.label or 'no label'} ({100 * exy:.1f} cm, {math.degrees(eth):.1f}° off)",
            )
        )
    if votes:
        text = ", ".join(f"{who}: {label}" for who, label in sorted(votes.items()))
        if is_conflict(votes):
            text += " — **conflict**"
        rows.append(("labels", text))
    else:
        rows.append(("labels", "none yet"))
    drawn = "initial guess" if use_guess else "match estimate"
    table = "\n".join(f"| {k} | {v} |" for k, v in rows)
    return f"| placed by | {drawn} |\n|---|---|\n{table}"
