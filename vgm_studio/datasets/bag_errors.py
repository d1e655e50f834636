"""Why a ROS bag cannot be read, said in one line with what to do about it.

``rosbags`` says "File magic is invalid" of a bag in the old 1.2 format and "Bag index looks
damaged" of a truncated one; neither tells a user what to run. A ROS 1 bag's first bytes (the
magic line and the header record holding ``index_pos``) say which of the three it is.
"""

from __future__ import annotations

import importlib
import sqlite3
import struct
from pathlib import Path

from rosbags.highlevel import AnyReaderError
from rosbags.rosbag1 import ReaderError as Rosbag1Error
from rosbags.rosbag2 import ReaderError as Rosbag2Error
from rosbags.serde import SerdeError
from rosbags.typesys import TypesysError

from vgm_studio.errors import InputError

ROS1_MAGIC = b"#ROSBAG V2.0\n"
REINDEX = "rebuild its index with `rosbag reindex {name}` (ROS 1), then read it again"
CONVERT = "or convert it with `rosbags-convert --src {name} --dst OUT` and read OUT"


def _optional_error(module: str, name: str) -> tuple[type[Exception], ...]:
    """An exception class of a module rosbags may use, or nothing when it is not installed."""
    try:
        found = getattr(importlib.import_module(module), name, None)
    except ImportError:
        return ()
    return (found,) if isinstance(found, type) and issubclass(found, Exception) else ()


# What ``rosbags`` raises on a bag it cannot read: its own errors, and what its parsers and
# decompressors let through on a damaged file (short reads, bad headers, a broken sqlite
# database, bad YAML, bad lz4/bz2/zstd data, a damaged length field asking for terabytes).
BAG_ERRORS: tuple[type[Exception], ...] = (
    AnyReaderError,
    Rosbag1Error,
    Rosbag2Error,
    SerdeError,
    TypesysError,
    OSError,
    EOFError,
    sqlite3.Error,
    struct.error,
    ValueError,
    KeyError,
    IndexError,
    TypeError,
    AttributeError,
    AssertionError,
    RuntimeError,
    MemoryError,
    *_optional_error("apsw", "Error"),
    *_optional_error("backports.zstd", "ZstdError"),
    *_optional_error("zstandard", "ZstdError"),
)


def one_line(err: BaseException) -> str:
    """An exception's message on one line (its class name when it has none)."""
    if isinstance(err, MemoryError):
        return "out of memory (a damaged length field?)"
    text = " ".join(str(err).split())
    return text or type(err).__name__


def _index_pos(head: bytes) -> int | None:
    """``index_pos`` from a ROS 1 (2.0) bag's header record, None when it cannot be parsed."""
    start = len(ROS1_MAGIC)
    try:
        (size,) = struct.unpack_from("<I", head, start)
        fields = head[start + 4 : start + 4 + size]
        at = fields.find(b"index_pos=")
        return None if at < 0 else int(struct.unpack_from("<Q", fields, at + 10)[0])
    except struct.error:
        return None


def ros1_problem(path: Path) -> str | None:
    """What is wrong with a ``.bag`` file that its first bytes show, None when they look right."""
    try:
        size = path.stat().st_size
        with path.open("rb") as f:
            head = f.read(4096)
    except OSError as err:
        return f"cannot be read ({err.strerror or err})"
    name = path.name
    if size == 0:
        return "an empty file (the recording never started?)"
    if head.startswith((b"#ROSRECORD", b"#ROSLOG", b"#ROSBAG V1")):
        version = head.split(b"\n", 1)[0].decode("ascii", "replace").lstrip("#")
        return (
            f"ROS bag format {version} is older than 2.0, the only ROS 1 format rosbags reads; "
            f"rewrite it as 2.0 with a ROS 1 install (`rosbag fix {name} NEW.bag`)"
        )
    if not head.startswith(ROS1_MAGIC):
        return f"not a ROS 1 bag (it does not start with {ROS1_MAGIC.strip().decode()})"
    index_pos = _index_pos(head)
    if index_pos == 0:
        return f"the bag has no index (its recording was cut short?); {REINDEX.format(name=name)}"
    if index_pos is not None and index_pos >= size:
        return (
            f"the file is truncated ({size:,} bytes, its index starts at byte {index_pos:,}); "
            f"{REINDEX.format(name=name)} to keep what was recorded"
        )
    return None


def bag_error(path: Path, err: BaseException) -> InputError:
    """The one-line error for a bag ``rosbags`` failed on: the cause when the file shows it."""
    if path.is_file() and path.suffix == ".bag":
        problem = ros1_problem(path)
        if problem is None:
            name = path.name
            problem = (
                f"rosbags rejects its index ({one_line(err)}); "
                f"{REINDEX.format(name=name)}, {CONVERT.format(name=name)}"
            )
        return InputError(path, f"not a readable ROS bag: {problem}")
    return InputError(path, f"not a readable ROS bag: {one_line(err)}")
