"""The OFF mesh format (Geomview; ModelNet's format), ASCII only.

Handles the quirks of real ModelNet files: the counts glued to the keyword
(``OFF1234 5678 0``), ``#`` comments, blank lines, and faces followed by colour values.
``COFF``/``NOFF``/``CNOFF`` headers (per-vertex colours and normals) are accepted; a mesh
is sampled by area, and a file with no faces yields its vertices (with normals for ``NOFF``).
"""

from __future__ import annotations

import numpy as np

from .mesh import Mesh, triangulate
from .pointcloud import PointCloud

__all__ = ["off_mesh", "parse_off"]


def parse_off(raw: bytes, n_samples: int | None = None, seed: int | None = 0) -> PointCloud:
    """Read an OFF file's bytes: a mesh is sampled by area, a face-less file gives vertices.

    Raises
    ------
    ValueError
        Not an OFF file, binary OFF, truncated data, or face indices out of range.
    """
    return off_mesh(raw).sampled(n_samples, seed)


def off_mesh(raw: bytes) -> Mesh:
    """Read an OFF file's bytes as stored: vertices and triangles (None without faces), and
    the vertices' normals (``NOFF``) for a face-less file.

    Raises
    ------
    ValueError
        As :func:`parse_off`.
    """
    text = raw.decode("latin-1")
    # (file line number, content): comments and blank lines are skipped, but errors name the
    # line of the file.
    numbered = [(i + 1, line.split("#", 1)[0].strip()) for i, line in enumerate(text.splitlines())]
    numbered = [(i, line) for i, line in numbered if line]
    lines = [line for _, line in numbered]
    if not lines:
        raise ValueError("OFF file has no content")
    first = lines[0]
    keyword = first.split()[0]
    stem = keyword.rstrip("0123456789.-+")
    if not stem.endswith("OFF") or set(stem[:-3]) - set("CN"):
        raise ValueError(f"not an OFF file (first line {first[:40]!r}; supported: OFF, COFF, NOFF)")
    rest = first[len(stem) :].split()
    if rest and rest[0].upper() == "BINARY":
        raise ValueError("binary OFF is not supported (convert it to ASCII OFF or PLY)")
    body = 1
    if not rest:
        if len(lines) < 2:
            raise ValueError("OFF file is truncated (no vertex/face counts)")
        rest = lines[1].split()
        body = 2
    if len(rest) < 2 or not all(w.isascii() and w.lstrip("+-").isdigit() for w in rest[:2]):
        raise ValueError(f"OFF counts line is malformed: {' '.join(rest)[:60]!r}")
    n_vertices, n_faces = int(rest[0]), int(rest[1])
    if n_vertices < 0 or n_faces < 0:
        raise ValueError("OFF counts are negative")
    vertex_lines = lines[body : body + n_vertices]
    face_lines = lines[body + n_vertices : body + n_vertices + n_faces]
    if len(vertex_lines) < n_vertices or len(face_lines) < n_faces:
        raise ValueError(
            f"OFF file is truncated: header says {n_vertices} vertices and {n_faces} faces, "
            f"found {len(vertex_lines)} and {len(face_lines)}"
        )
    if n_vertices == 0:
        raise ValueError("OFF file has no vertices")
    try:
        table = np.loadtxt(vertex_lines, dtype=np.float64, ndmin=2, comments=None)
    except ValueError as exc:
        raise ValueError(f"malformed OFF vertex lines ({exc})") from None
    if table.shape[1] < 3:
        raise ValueError(f"OFF vertex lines have {table.shape[1]} values, need at least x y z")
    vertices = table[:, :3]
    if n_faces == 0:
        normals = table[:, 3:6] if "N" in stem[:-3] and table.shape[1] >= 6 else None
        return Mesh(vertices, None, normals)
    face_numbers = [i for i, _ in numbered[body + n_vertices : body + n_vertices + n_faces]]
    counts, items = _faces(face_lines, face_numbers)
    _check_indices(counts, items, n_vertices, face_numbers)
    return Mesh(vertices, triangulate(counts, items))


def _faces(face_lines: list[str], numbers: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Per-face vertex counts and flat indices (trailing colour values are ignored)."""
    try:
        table = np.loadtxt(face_lines, dtype=np.int64, ndmin=2, comments=None)
    except (ValueError, OverflowError):
        table = None  # ragged rows (mixed polygon sizes, colours on some faces) or bad values
    if table is not None:
        n = int(table[0, 0])
        if n >= 0 and (table[:, 0] == n).all() and table.shape[1] >= n + 1:
            return np.full(len(table), n, np.int64), table[:, 1 : n + 1].reshape(-1)
    counts: list[int] = []
    items: list[int] = []
    for number, line in zip(numbers, face_lines, strict=True):
        words = line.split()
        try:
            n = int(words[0])
            if n < 0 or len(words) < n + 1:
                raise ValueError
            items.extend(int(w) for w in words[1 : n + 1])
        except (IndexError, ValueError):
            raise ValueError(f"malformed OFF face on line {number}: {line[:80]!r}") from None
        counts.append(n)
    return np.asarray(counts, np.int64), _indices(items, counts, numbers)


def _indices(items: list[int], counts: list[int], numbers: list[int]) -> np.ndarray:
    """The flat indices as int64; a value beyond int64 (Python parses any length) names its
    line instead of overflowing."""
    try:
        return np.asarray(items, np.int64)
    except OverflowError:
        big = next(k for k, v in enumerate(items) if not -(2**63) <= v < 2**63)
        face = int(np.searchsorted(np.cumsum(counts), big, side="right"))
        raise ValueError(
            f"OFF face on line {numbers[face]}: vertex index {items[big]} is out of range"
        ) from None


def _check_indices(
    counts: np.ndarray, items: np.ndarray, n_vertices: int, numbers: list[int]
) -> None:
    """Every face index names a vertex; the message names the face's line."""
    bad = (items < 0) | (items >= n_vertices)
    if not bad.any():
        return
    flat = int(np.argmax(bad))
    face = int(np.searchsorted(np.cumsum(counts), flat, side="right"))
    raise ValueError(
        f"OFF face on line {numbers[face]}: vertex index {int(items[flat])} is not a vertex "
        f"of the {n_vertices} in the file"
    )
