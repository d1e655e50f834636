"""The schema of an exported label row (JSONL or CSV), declared once.

A row is an edge (``EdgeRow``) whose ``label`` is the annotator's, plus ``annotator``,
``labeled_at`` and ``note``; ``reference_label`` keeps the edge's own label. CSV cells that a
spreadsheet would run as a formula are written with a leading ``'`` (OWASP's rule for CSV
injection) and read back without it, so export → import gives back the same text.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from vgm_studio.errors import InputError
from vgm_studio.matching.edge_schema import MAX_TEXT_CHARS, Name, Text, describe
from vgm_studio.matching.edges import Edge

MAX_NOTE_CHARS = 4000
# A cell starting with one of these is a formula to a spreadsheet; "'" is escaped too, so
# that reading a cell back is exact.
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r", "'")


def _annotator(value: str) -> str:
    if not value.strip():
        raise ValueError("is empty (is this an exported label file?)")
    return value


def _aware_time(value: str) -> str:
    try:
        when = datetime.fromisoformat(value)
    except ValueError:
        raise ValueError("is not an ISO 8601 time") from None
    if when.tzinfo is None or when.utcoffset() is None:
        raise ValueError("has no time zone (write it as e.g. 2026-01-31T12:00:00+00:00)")
    return value


class LabelFields(BaseModel):
    """The annotator's part of a row; the rest of the row is an ``EdgeRow``."""

    model_config = ConfigDict(extra="ignore")

    annotator: Annotated[
        Name, Field(min_length=1, max_length=MAX_TEXT_CHARS), AfterValidator(_annotator)
    ]
    label: Literal["success", "failure"]
    labeled_at: Annotated[str, Field(max_length=64), AfterValidator(_aware_time)]
    note: Annotated[Text, Field(max_length=MAX_NOTE_CHARS)] | None = None
    reference_label: Literal["success", "failure", "ambiguous"] | None = None


def aware(labeled_at: str) -> datetime:
    """A stored ``labeled_at`` as an aware datetime (a zone-less one is taken as UTC)."""
    when = datetime.fromisoformat(labeled_at)
    return when if when.tzinfo is not None else when.replace(tzinfo=timezone.utc)


def parse_label_row(
    obj: Any, path: Path | str | None, line: int | None
) -> tuple[Edge, LabelFields]:
    """Validates one row: its edge and its label.

    Raises:
        InputError: ``file:line: field: what is wrong``.
    """
    if not isinstance(obj, dict):
        raise InputError(path, "a label row must be a JSON object", line)
    try:
        fields = LabelFields.model_validate(obj)
    except ValidationError as exc:
        raise InputError(path, describe(exc), line) from None
    edge = Edge.from_json({**obj, "label": fields.reference_label}, path, line)
    return edge, fields


def escape_cell(value: Any) -> Any:
    """A text cell a spreadsheet shows as text, never runs: a leading ``'`` where needed."""
    if isinstance(value, str) and value.startswith(FORMULA_STARTS):
        return "'" + value
    return value


def unescape_cell(value: str) -> str:
    """Reverses ``escape_cell``."""
    return value[1:] if value.startswith("'") else value
