"""ROS bags of ``sensor_msgs/PointCloud2`` messages as the scans of a batch, read with
``rosbags`` (pure Python, ``pip install 'pointclm[io]'``), without ROS.

A bag is a ROS 1 ``.bag`` file, a rosbag2 folder (with its ``metadata.yaml``), or a bare
rosbag2 ``.mcap`` or ``.db3`` file. Each PointCloud2 message is one scan, named
``BAG#TOPIC@STAMP``: the bag's path, the topic, and the message's timestamp in the bag in
nanoseconds (``@STAMP+K`` for the K-th of several messages of a topic logged at the same
nanosecond). Such a name is what a batch's JSON line records as its ``scan`` and what
``--resume`` matches; given as a scan itself it names that one message, and ``BAG#TOPIC``
names every message of one topic. A bag with several PointCloud2 topics gives every
message of each, topic by topic (sorted by name), each in the order logged.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from ..errors import InputError, PathNotFoundError
from ..io.pointcloud import PointCloud
from .pointcloud2 import read_pointcloud2

__all__ = ["BAG_SUFFIXES", "bag_scans", "is_bag", "is_bag_message", "read_bag_scan"]

#: Files read as bags (besides rosbag2 folders).
BAG_SUFFIXES: tuple[str, ...] = (".bag", ".mcap", ".db3")
_POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
#: The part after the bag's path: a topic (ROS names hold no "#" or "@"), then a stamp.
_REF = re.compile(r"^(?P<topic>/[^#@]*)(?:@(?P<stamp>\d+)(?:\+(?P<k>\d+))?)?$")


def is_bag(path: str | os.PathLike[str]) -> bool:
    """Whether `path` is a bag: a ``.bag``/``.mcap``/``.db3`` file or a rosbag2 folder."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix.lower() in BAG_SUFFIXES and p.is_file()


def _split(scan: str) -> tuple[str, re.Match[str]] | None:
    """The bag and the topic/stamp match of ``BAG#TOPIC[@STAMP[+K]]``, or None."""
    bag, sep, rest = scan.rpartition("#")
    if not sep:
        return None
    match = _REF.match(rest)
    if match is None or not is_bag(bag):
        return None
    return bag, match


def is_bag_message(scan: str | os.PathLike[str]) -> bool:
    """Whether `scan` names one message of a bag (``BAG#TOPIC@STAMP``)."""
    split = _split(os.fspath(scan))
    return split is not None and split[1]["stamp"] is not None


def _rosbags() -> tuple[Any, Any]:
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ImportError("reading ROS bags needs rosbags: pip install 'pointclm[io]'") from None
    # rosbag2 bags written before message definitions were stored in them need a default.
    return AnyReader, get_typestore(Stores.LATEST)


def _open(bag: str) -> Any:
    reader_cls, typestore = _rosbags()
    try:
        reader = reader_cls([Path(bag)], default_typestore=typestore)
        reader.open()
    except Exception as err:  # noqa: BLE001 - rosbags' errors for a damaged or odd bag
        raise InputError(
            f"{bag}: cannot read it as a ROS bag ({type(err).__name__}: {err})"
        ) from None
    return reader


def _clouds(reader: Any, bag: str, topic: str | None) -> list[Any]:
    """The bag's PointCloud2 connections (of `topic` if given), or an InputError."""
    conns = [c for c in reader.connections if c.msgtype == _POINTCLOUD2]
    if topic is not None:
        conns = [c for c in conns if c.topic == topic]
    if not conns:
        topics = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
        wanted = f" on {topic}" if topic is not None else ""
        raise InputError(
            f"{bag}: no sensor_msgs/PointCloud2 messages{wanted} (topics: "
            f"{', '.join(topics) or 'none'})"
        )
    return conns


def bag_scans(source: str | os.PathLike[str]) -> list[str]:
    """The scan names (``BAG#TOPIC@STAMP``) of every PointCloud2 message in a bag, or of one
    topic (``BAG#TOPIC``), or `source` itself when it names one message.

    Raises
    ------
    InputError
        If the bag cannot be read, or holds no PointCloud2 message (on that topic).
    """
    text = os.fspath(source)
    split = _split(text)
    if split is not None and split[1]["stamp"] is not None:
        return [text]
    bag, topic = (text, None) if split is None else (split[0], split[1]["topic"])
    reader = _open(bag)
    try:
        by_topic: dict[str, list[str]] = {}
        seen: dict[tuple[str, int], int] = {}
        for conn, stamp, _ in reader.messages(connections=_clouds(reader, bag, topic)):
            k = seen.get((conn.topic, stamp), 0)
            seen[(conn.topic, stamp)] = k + 1
            name = f"{bag}#{conn.topic}@{stamp}" + (f"+{k}" if k else "")
            by_topic.setdefault(conn.topic, []).append(name)
    finally:
        reader.close()
    if not by_topic:
        raise InputError(f"{text}: the bag's PointCloud2 topics hold no message")
    return [name for t in sorted(by_topic) for name in by_topic[t]]


def read_bag_scan(scan: str | os.PathLike[str]) -> PointCloud:
    """The points of one bag message named ``BAG#TOPIC@STAMP[+K]`` (see :func:`bag_scans`).

    Raises
    ------
    PathNotFoundError
        If the bag does not exist.
    InputError
        If the bag cannot be read or has no such message, or the message is not a valid
        PointCloud2 (the message says what is wrong); both are ValueErrors.
    """
    text = os.fspath(scan)
    split = _split(text)
    if split is None or split[1]["stamp"] is None:
        bag = text.rpartition("#")[0] or text
        if not os.path.exists(bag):
            raise PathNotFoundError(f"{bag}: no such bag")
        raise InputError(f"{text}: not a bag message name (BAG#TOPIC@STAMP)")
    bag, match = split
    stamp, k = int(match["stamp"]), int(match["k"] or 0)
    reader = _open(bag)
    try:
        conns = _clouds(reader, bag, match["topic"])
        found = list(reader.messages(connections=conns, start=stamp, stop=stamp + 1))
        if len(found) <= k:
            raise InputError(f"{text}: the bag has no such message on {match['topic']}")
        conn, _, raw = found[k]
        message = reader.deserialize(raw, conn.msgtype)
    finally:
        reader.close()
    try:
        return read_pointcloud2(message)
    except ValueError as err:
        raise InputError(f"{text}: {err}") from None
