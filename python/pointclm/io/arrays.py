"""NumPy array files: ``.npy`` and ``.npz`` holding (N, 3) points or (N, 6) points+normals.

Nothing here unpickles: object arrays are refused from the header, before any data is read
(loading a pickle runs code from the file, which a point cloud reader must never do).

Sizes are checked before allocating: ``np.load`` allocates the array a header declares and
only then notices that the file is shorter, so a 100-byte ``.npy`` claiming a (10**9, 3)
array would reserve 24 GB. Here the header is parsed first and its shape times its item
size must match the bytes that follow. In an ``.npz`` archive only the members needed are
opened (``points`` or the only array, ``normals``, ``colors``); each member's declared
uncompressed size must be one deflate can produce from its compressed size, and the member
is streamed through its header into exactly the declared number of bytes. Shapes are checked
from the headers first (``normals`` and ``colors`` must match the points), so memory is
bounded by the arrays returned: a member that is not used, or is refused, is never
decompressed, and a used one is decompressed a chunk at a time into its array.
"""

from __future__ import annotations

import functools
import io
import math
import zipfile
from collections.abc import Callable
from typing import IO

import numpy as np

from .pointcloud import PointCloud, finite_cloud, unit_colors

__all__ = ["NpzArchive", "parse_npy", "parse_npz", "read_npy", "read_npz_members"]

_MAGIC = b"\x93NUMPY"
#: Deflate's largest expansion: a 258-byte match costs at least 2 bits (1032:1), plus the
#: block overhead the constant below absorbs.
DEFLATE_MAX_EXPANSION = 1032
#: Members named in an archive that the reader may open.
_WANTED = ("points", "normals", "colors")


def _header(
    fp: IO[bytes], what: str, kinds: str = "biuf"
) -> tuple[tuple[int, ...], bool, np.dtype]:
    """Shape, Fortran order and dtype from a ``.npy`` header, refusing object dtypes and
    kinds other than ``kinds``."""
    try:
        version = np.lib.format.read_magic(fp)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(fp)
        elif version in ((2, 0), (3, 0)):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(fp)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
    except MemoryError:
        raise
    except Exception as exc:  # numpy's header parser raises several types on corrupt headers
        raise ValueError(
            f"{what}: not a readable .npy header ({type(exc).__name__}: {exc})"
        ) from None
    if dtype.hasobject:
        raise ValueError(f"{what} holds Python objects (a pickle); pointclm never unpickles files")
    if dtype.kind not in kinds or dtype.fields is not None or dtype.subdtype is not None:
        raise ValueError(f"{what} has dtype {dtype}, expected a numeric array")
    return tuple(int(n) for n in shape), bool(fortran), dtype


def _array(
    data: bytes | memoryview, shape: tuple[int, ...], fortran: bool, dtype: np.dtype
) -> np.ndarray:
    arr = np.frombuffer(data, dtype=dtype, count=math.prod(shape))
    # A writable copy, as np.load would give (frombuffer over bytes is read-only).
    return arr.reshape(shape, order="F" if fortran else "C").copy()


def read_npy(raw: bytes, what: str = "the array") -> np.ndarray:
    """A numeric array from the bytes of a ``.npy`` file, sizes checked before reading.

    Raises
    ------
    ValueError
        Not a ``.npy`` file, an object (pickled) or non-numeric dtype, or data shorter or
        longer than the header declares.
    """
    fp = io.BytesIO(raw)
    shape, fortran, dtype = _header(fp, what)
    start = fp.tell()
    need = math.prod(shape) * dtype.itemsize
    have = len(raw) - start
    if need != have:
        raise ValueError(
            f"{what}: the header declares shape {shape} of {dtype} ({need} bytes), "
            f"the file holds {have} bytes of data"
        )
    return _array(memoryview(raw)[start:], shape, fortran, dtype)


def read_npz_members(
    raw: bytes, wanted: tuple[str, ...] | None = _WANTED, kinds: str = "biuf"
) -> tuple[dict[str, np.ndarray], list[str]]:
    """The arrays of an ``.npz`` archive named in ``wanted`` (or its only array, when it has
    just one; every array when ``wanted`` is None), and the names of all its arrays; no
    other member is decompressed.

    Raises
    ------
    ValueError
        Not a zip archive, a member compressed with anything but deflate (or stored), a
        declared size that its compressed size cannot hold, or a member :func:`read_npy`
        refuses.
    """
    with NpzArchive(raw) as archive:
        if wanted is None or len(archive.names) == 1:
            names = archive.names
        else:
            names = [n for n in wanted if n in archive.names]
        return {name: archive.array(name, kinds) for name in names}, archive.names


class NpzArchive:
    """An ``.npz`` archive opened for reading single members: nothing is decompressed until
    :meth:`array` asks for a member, and then only that member, straight into its array
    (no second copy), after its header has been checked (by ``check`` too, which sees the
    shape before any data is decompressed)."""

    def __init__(self, raw: bytes) -> None:
        try:
            self._zip = zipfile.ZipFile(io.BytesIO(raw))
        except MemoryError:
            raise
        except Exception as exc:  # BadZipFile, and a few others on corrupt directories
            raise ValueError(f"not a readable .npz archive ({type(exc).__name__}: {exc})") from None
        self._total = len(raw)
        self._members = {
            (info.filename[:-4] if info.filename.endswith(".npy") else info.filename): info
            for info in self._zip.infolist()
            if not info.is_dir()
        }
        #: The names of the archive's arrays (file names without ``.npy``).
        self.names: list[str] = list(self._members)

    def __enter__(self) -> NpzArchive:
        return self

    def __exit__(self, *exc: object) -> None:
        self._zip.close()

    def array(
        self,
        name: str,
        kinds: str = "biuf",
        check: Callable[[tuple[int, ...]], None] | None = None,
    ) -> np.ndarray:
        """The member ``name`` as an array; ``check(shape)`` may refuse it (by raising
        ValueError) from its header, before its data is decompressed."""
        return _member(self._zip, self._members[name], self._total, name, kinds, check)


def _member(
    archive: zipfile.ZipFile,
    info: zipfile.ZipInfo,
    total: int,
    name: str,
    kinds: str,
    check: Callable[[tuple[int, ...]], None] | None = None,
) -> np.ndarray:
    what = f"array {name!r}"
    if info.compress_type == zipfile.ZIP_STORED:
        bound = info.compress_size
    elif info.compress_type == zipfile.ZIP_DEFLATED:
        bound = DEFLATE_MAX_EXPANSION * info.compress_size + 1024
    else:
        raise ValueError(
            f"{what} uses zip compression method {info.compress_type}; numpy writes only "
            "stored or deflated members"
        )
    if info.compress_size > total or info.file_size > bound:
        raise ValueError(
            f"{what}: the archive declares {info.file_size} bytes from {info.compress_size} "
            f"compressed bytes in a {total}-byte file, which no archive can hold"
        )
    try:
        with archive.open(info) as fh:
            shape, fortran, dtype = _header(fh, what, kinds)
            need = math.prod(shape) * dtype.itemsize
            if need + fh.tell() != info.file_size:
                raise ValueError(
                    f"{what}: the header declares shape {shape} of {dtype} ({need} bytes), "
                    f"the archive member holds {info.file_size - fh.tell()} bytes of data"
                )
            if check is not None:
                check(shape)
            flat = np.empty(math.prod(shape), dtype=dtype)
            got = _read_into(fh, flat.view(np.uint8))
    except (ValueError, MemoryError):
        raise
    except Exception as exc:  # zlib, CRC and encryption errors from zipfile
        raise ValueError(
            f"{what}: unreadable archive member ({type(exc).__name__}: {exc})"
        ) from None
    if got != need:
        raise ValueError(f"{what}: the archive member is truncated")
    return flat.reshape(shape, order="F" if fortran else "C")


#: Bytes decompressed per read: the only buffer beside the array itself.
_CHUNK = 1 << 20


def _read_into(fh: IO[bytes], out: np.ndarray) -> int:
    """Fill the bytes ``out`` from ``fh`` a chunk at a time; the number of bytes read."""
    pos = 0
    while pos < len(out):
        data = fh.read(min(_CHUNK, len(out) - pos))
        if not data:
            break
        out[pos : pos + len(data)] = np.frombuffer(data, dtype=np.uint8)
        pos += len(data)
    return pos


def _split(arr: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(N, 3) -> points; (N, 6) -> points and normals."""
    _cloud_shape(arr.shape, what)
    return arr[:, :3], (arr[:, 3:6] if arr.shape[1] == 6 else None)


def parse_npy(raw: bytes) -> PointCloud:
    """Read a ``.npy`` file's bytes.

    Raises
    ------
    ValueError
        Not a ``.npy`` file, a pickled array, or a shape other than (N, 3) / (N, 6).
    """
    if not raw.startswith(_MAGIC):
        kind = "an .npz archive with a .npy name?" if raw.startswith(b"PK") else "no NUMPY magic"
        raise ValueError(f"not a readable .npy array ({kind})")
    points, normals = _split(read_npy(raw), "the array")
    return finite_cloud(points, normals)


def parse_npz(raw: bytes) -> PointCloud:
    """Read a ``.npz`` archive: key ``points`` (or its only array), optional ``normals``
    and ``colors`` (floats in [0, 1] or 8-bit integers). Shapes are checked from the
    members' headers, so a member that is not used, or has the wrong shape, is never
    decompressed.

    Raises
    ------
    ValueError
        Not an archive, no ``points`` key among several arrays, or mismatched shapes.
    """
    if raw.startswith(_MAGIC):
        # a .npy under an .npz name
        points, normals = _split(read_npy(raw), "array 'points'")
        return finite_cloud(points, normals)
    with NpzArchive(raw) as archive:
        names = archive.names
        if "points" in names:
            key = "points"
        elif len(names) == 1:
            key = names[0]
        else:
            raise ValueError(
                f"archive has no 'points' array and {len(names)} arrays "
                f"({', '.join(sorted(names)) or 'none'}); expected 'points' or a single array"
            )
        what = f"array {key!r}"
        points, normals = _split(archive.array(key, check=lambda s: _cloud_shape(s, what)), what)
        extras: dict[str, np.ndarray] = {}
        for name in ("normals", "colors"):
            if name in names and name != key:
                same = functools.partial(_same_shape, name=name, points=points.shape)
                extras[name] = archive.array(name, check=same)
    colors = extras.get("colors")
    normals = extras.get("normals", normals)
    return finite_cloud(points, normals, None if colors is None else unit_colors(colors))


def _cloud_shape(shape: tuple[int, ...], what: str) -> None:
    """(N, 3) or (N, 6), the shapes :func:`_split` takes."""
    if len(shape) != 2 or shape[1] not in (3, 6):
        raise ValueError(
            f"{what} has shape {shape}; expected (N, 3) points or (N, 6) points+normals"
        )


def _same_shape(shape: tuple[int, ...], name: str, points: tuple[int, ...]) -> None:
    if shape != points:
        raise ValueError(f"array {name!r} has shape {shape}, the points have {points}")
