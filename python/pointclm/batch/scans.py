"""The scans of a batch: files, folders and glob patterns expanded into one list, in a fixed
order (the order given; a folder's and a pattern's files sorted by name), without repeats.
A ROS bag (:mod:`pointclm.ros.bags`) gives one scan per PointCloud2 message."""

from __future__ import annotations

import glob
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import SUPPORTED_SUFFIXES, load_points

__all__ = ["expand_scans", "load_scan_points", "picture_names"]


def _is_pattern(text: str) -> bool:
    return glob.has_magic(text)


def _folder_files(folder: str) -> list[str]:
    names = sorted(
        n
        for n in os.listdir(folder)
        if n.lower().endswith(SUPPORTED_SUFFIXES) and os.path.isfile(os.path.join(folder, n))
    )
    if not names:
        raise InputError(
            f"scans: the folder {folder} holds no point-cloud file "
            f"({', '.join(SUPPORTED_SUFFIXES)})"
        )
    return [os.path.join(folder, n) for n in names]


def _expand_one(item: str) -> list[str]:
    from ..ros.bags import bag_scans, is_bag

    if is_bag(item) or is_bag(item.rpartition("#")[0] or item):
        return bag_scans(item)
    if os.path.isdir(item):
        return _folder_files(item)
    if _is_pattern(item) and not os.path.exists(item):
        found = sorted(p for p in glob.glob(item, recursive=True) if os.path.isfile(p))
        if not found:
            raise InputError(f"scans: the pattern {item!r} matches no file")
        return [s for p in found for s in (bag_scans(p) if is_bag(p) else [p])]
    # A plain path is taken as given even when missing: its line records the error, and
    # the batch goes on (a list of thousands should not stop at one stale name).
    return [item]


def expand_scans(scans: str | os.PathLike[str] | Iterable[str | os.PathLike[str]]) -> list[str]:
    """The scan files `scans` names: a file, a folder (its point-cloud files, by name), or a
    glob pattern (``**`` recurses), or a list of these. A file listed twice (under any
    spelling) is kept once, at its first place."""
    items = [scans] if isinstance(scans, str | os.PathLike) else list(scans)
    if not items:
        raise InputError("scans: no scan given")
    out: list[str] = []
    seen: set[str] = set()
    for item in items:
        if not isinstance(item, str | os.PathLike):
            raise InputError(f"scans: expected paths, got {type(item).__name__}")
        for path in _expand_one(os.fspath(item)):
            key = os.path.realpath(path)
            if key not in seen:
                seen.add(key)
                out.append(path)
    return out


def load_scan_points(scan: str) -> np.ndarray:
    """The (N, 3) points of one scan: a file (:func:`pointclm.io.load_points`) or a bag's
    message (:func:`pointclm.ros.bags.read_bag_scan`)."""
    from ..ros.bags import is_bag_message, read_bag_scan

    if is_bag_message(scan):
        return read_bag_scan(scan).points
    return load_points(scan)


def picture_names(scans: list[str]) -> list[str]:
    """A file name (without suffix) per scan for its PNG/PLY, unique within the batch: the
    scan's stem, or where two scans share one, its path from their common folder with "/"
    as "__" (and its suffix where even that repeats)."""
    stems = [Path(s).stem for s in scans]
    if len(set(stems)) == len(stems):
        return stems
    absolute = [os.path.abspath(s) for s in scans]
    root = os.path.commonpath([os.path.dirname(a) for a in absolute])
    relative = [os.path.relpath(a, root) for a in absolute]
    names = [os.path.splitext(r)[0].replace(os.sep, "__") for r in relative]
    if len(set(names)) != len(names):
        names = [r.replace(os.sep, "__") for r in relative]
    return names
