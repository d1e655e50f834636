"""The rules a comparison must hold (``--fail-on error-increase=10%,new-false-loops=0``).

Each rule is ``NAME=LIMIT``. The error rules take a share of the base run's error (``10%``),
an absolute amount (``0.005``: metres, or degrees for ``rot-error-increase``) or ``noise``
(beyond the run-to-run noise, ``diff.Noise``); the count rules take the most allowed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from vgm_studio.compare.diff import Comparison, ErrorChange
from vgm_studio.errors import InputError

# Rule name → what it counts or measures, for --help and the error on an unknown name.
RULES: dict[str, str] = {
    "error-increase": "the after relation error (m) rose by more than LIMIT",
    "rot-error-increase": "the after rotation error (°) rose by more than LIMIT",
    "new-false-loops": "more than LIMIT wrong loops newly kept",
    "lost-right-loops": "more than LIMIT right loops newly dropped",
    "newly-kept": "more than LIMIT loops newly kept",
    "newly-dropped": "more than LIMIT loops newly dropped",
    "flipped": "more than LIMIT loops decided otherwise",
    "moved-keyframes": "more than LIMIT keyframes moved past the threshold",
}
_ERROR_RULES = {"error-increase": "m", "rot-error-increase": "°"}


@dataclass(frozen=True)
class Rule:
    """One rule as given.

    Attributes:
        name: One of ``RULES``.
        limit: The limit: a count, an amount, or a share of the base (``relative``).
        relative: ``limit`` is a share of the base run's value (``10%`` → 0.10).
        noise: The limit is the run-to-run noise.
        text: The rule as written, for messages.
    """

    name: str
    limit: float
    relative: bool = False
    noise: bool = False
    text: str = ""


@dataclass(frozen=True)
class Outcome:
    """A rule judged: whether it holds, and the figure it was judged on."""

    rule: Rule
    holds: bool
    detail: str


def parse_rules(text: str, where: str = "--fail-on") -> list[Rule]:
    """Parses ``NAME=LIMIT[,NAME=LIMIT…]``.

    Raises:
        InputError: ``--fail-on: what is wrong`` for an unknown name or a bad limit.
    """
    rules = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        name, eq, value = (s.strip() for s in part.partition("="))
        if name not in RULES:
            raise InputError(where, f"unknown rule {name!r}; the rules: {', '.join(RULES)}")
        if not eq or not value:
            raise InputError(where, f"{part!r} needs a limit: {name}=LIMIT")
        rules.append(_rule(name, value, part, where))
    return rules


def _rule(name: str, value: str, text: str, where: str) -> Rule:
    error_rule = name in _ERROR_RULES
    if error_rule and value == "noise":
        return Rule(name, 0.0, noise=True, text=text)
    relative = error_rule and value.endswith("%")
    try:
        limit = float(value[:-1] if relative else value)
    except ValueError:
        limit = math.nan
    if not math.isfinite(limit) or limit < 0:
        kind = "a share (10%), an amount (0.005) or noise" if error_rule else "a count (0, 1, …)"
        raise InputError(where, f"{text!r}: the limit must be {kind}, at least 0")
    if not error_rule and limit != int(limit):
        raise InputError(where, f"{text!r}: the limit must be a whole count")
    return Rule(name, limit / 100 if relative else limit, relative=relative, text=text)


def check_rules(rules: list[Rule], comparison: Comparison) -> list[Outcome]:
    """Judges each rule on the comparison.

    Raises:
        InputError: An error rule where a run has no after relation error to judge it by.
    """
    return [_judge(rule, comparison) for rule in rules]


def _judge(rule: Rule, c: Comparison) -> Outcome:
    if rule.name in _ERROR_RULES:
        change = c.error("after", _ERROR_RULES[rule.name])
        if change is None:
            missing = c.base if "after" not in c.base.errors else c.new
            raise InputError(
                missing.path,
                f"{rule.text}: this run has no relation errors (run slam with --relations "
                "or on a log with reference poses)",
            )
        return _judge_error(rule, change)
    loops = c.loops
    counted = {
        "new-false-loops": len(loops.new_false),
        "lost-right-loops": len(loops.lost_right),
        "newly-kept": len(loops.newly_kept),
        "newly-dropped": len(loops.newly_dropped),
        "flipped": len(loops.flipped),
        "moved-keyframes": len(c.moved),
    }[rule.name]
    return Outcome(rule, counted <= rule.limit, f"{counted} (at most {rule.limit:g})")


def _judge_error(rule: Rule, e: ErrorChange) -> Outcome:
    if rule.noise:
        allowed = e.noise
    elif rule.relative:
        allowed = rule.limit * abs(e.base)
    else:
        allowed = rule.limit
    digits = 4 if e.unit == "m" else 3
    share = f"{e.relative:+.1%}" if math.isfinite(e.relative) else "from 0"
    detail = (
        f"after {e.base:.{digits}f} → {e.new:.{digits}f} {e.unit} ({share}; "
        f"at most +{allowed:.{digits}f} {e.unit})"
    )
    return Outcome(rule, e.delta <= allowed, detail)
