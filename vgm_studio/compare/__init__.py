"""Two runs of one log compared: relation errors against the run-to-run noise, loops matched
by scan pair, keyframes that moved, the after maps over each other, and rules a CI job
fails on (``vgm-studio compare``)."""

from vgm_studio.compare.diff import CompareConfig, Comparison, Noise, compare_runs
from vgm_studio.compare.rules import Outcome, Rule, check_rules, parse_rules
from vgm_studio.compare.runs import Run, load_run, same_subject

__all__ = [
    "CompareConfig",
    "Comparison",
    "Noise",
    "Outcome",
    "Rule",
    "Run",
    "check_rules",
    "compare_runs",
    "load_run",
    "parse_rules",
    "same_subject",
]
