"""Which topic of a ROS bag is read for each message type: the one asked for, the only one,
or, for scans, ``/scan`` among several (said in a warning); else a one-line refusal that lists
the topics."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from vgm_studio.errors import InputError

if TYPE_CHECKING:
    from rosbags.interfaces import TopicInfo

LASER_SCAN_TYPES = frozenset({"sensor_msgs/msg/LaserScan", "sensor_msgs/LaserScan"})
ODOMETRY_TYPES = frozenset({"nav_msgs/msg/Odometry", "nav_msgs/Odometry"})
# The LaserScan topic taken, with a warning, when a bag has several and none is asked for.
DEFAULT_SCAN_TOPIC = "/scan"


def describe_topics(topics: Mapping[str, TopicInfo]) -> str:
    """The bag's topics with their types and counts, for a refusal's message."""
    if not topics:
        return "the bag has no topics"
    listed = ", ".join(f"{name} ({info.msgtype}, {info.msgcount})" for name, info in topics.items())
    return f"topics found: {listed}"


@dataclass(frozen=True)
class TopicKind:
    """A message type a bag is read for, and how its topic is chosen.

    Attributes:
        types: Its type names (ROS 1 and ROS 2 spellings).
        what: Its name in messages.
        option: The option that chooses its topic.
        required: A bag without it is refused.
        default: The topic taken, with a warning, when the bag has several and none is asked
            for (None: refuse, naming them).
    """

    types: frozenset[str]
    what: str
    option: str
    required: bool
    default: str | None = None


SCANS = TopicKind(
    LASER_SCAN_TYPES, "sensor_msgs/LaserScan", "--scan-topic", True, DEFAULT_SCAN_TOPIC
)
# No usual name to fall back on: /odom and /odometry/filtered are both common, and reading
# the wrong one misplaces every scan.
ODOMETRY = TopicKind(ODOMETRY_TYPES, "nav_msgs/Odometry", "--odom-topic", False)


def choose_topic(
    path: Path,
    topics: Mapping[str, TopicInfo],
    kind: TopicKind,
    wanted: str | None,
    warnings: list[str],
) -> str | None:
    """The topic to read for one message type: the one asked for, else the only one, else
    the kind's default when it is one of several (said in ``warnings``)."""
    what, option = kind.what, kind.option
    candidates = sorted(name for name, info in topics.items() if info.msgtype in kind.types)
    if wanted is not None:
        if wanted in candidates:
            return wanted
        if wanted in topics:
            problem = f"{option} {wanted} carries {topics[wanted].msgtype}, not {what}"
        else:
            problem = f"{option} {wanted} is not in this bag"
        raise InputError(path, f"{problem}; {describe_topics(topics)}")
    if len(candidates) == 1:
        return candidates[0]
    if len(candidates) > 1 and kind.default in candidates:
        others = ", ".join(c for c in candidates if c != kind.default)
        warnings.append(
            f"{path}: {len(candidates)} {what} topics; reading {kind.default} (not {others}); "
            f"choose another with {option}"
        )
        return kind.default
    if len(candidates) > 1:
        raise InputError(
            path,
            f"{len(candidates)} {what} topics ({', '.join(candidates)}); choose one with "
            f"{option} TOPIC",
        )
    if kind.required:
        raise InputError(path, f"no {what} topic in this bag; {describe_topics(topics)}")
    return None
