"""Hostile files: memory bombs, lying sizes, integers that do not fit, FIFOs and devices,
pickles. Named cases for each class of hostile file, then hypothesis-generated malformed files of
every supported format.

Every read runs under :func:`hardening.bounded`: a 10 s limit per case, an address-space cap
of the process's size + 1 GiB, and a traced-allocation bound. The files are a few KB, so a
``MemoryError`` is counted as a failure here (it would mean the reader believed a size the
file cannot hold), as is any exception other than ValueError / FileNotFoundError.
"""

from __future__ import annotations

import io
import os
import re
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hardening import CASES, bounded, expect_clean, write_counts
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pointclm.io import PointCloud, read_open3d_feature, read_point_cloud
from pointclm.io.arrays import read_npz_members

#: Fixed budget and derandomised search: CI sees the same cases every run.
SETTINGS = settings(
    max_examples=200,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
#: Traced allocations one read of a file of ``n`` bytes may make: a constant for numpy's and
#: Python's working set, plus a multiple of the file (text parsing holds a line per row).
MEMORY_BASE = 4 << 20
MEMORY_PER_BYTE = 400


@pytest.fixture(scope="module", autouse=True)
def _counts() -> object:
    yield
    write_counts("files")


def read_bounded(path: Path, **kwargs: object) -> object:
    """read_point_cloud under the time and memory limits; the result or the allowed error."""
    size = path.stat().st_size if path.is_file() else 0
    with bounded() as usage:
        out = expect_clean(lambda: read_point_cloud(path, **kwargs), allow_memory_error=False)
    limit = MEMORY_BASE + MEMORY_PER_BYTE * size
    assert usage.peak_bytes <= limit, f"reading {size} bytes peaked at {usage.peak_bytes} bytes"
    if isinstance(out, PointCloud):
        assert out.points.dtype == np.float64 and np.isfinite(out.points).all()
    if isinstance(out, BaseException):
        assert str(path) in str(out), f"the error does not name the file: {out}"
    return out


def write(tmp: Path, name: str, raw: bytes) -> Path:
    path = tmp / name
    path.write_bytes(raw)
    return path


def fails(out: object, pattern: str) -> None:
    assert isinstance(out, ValueError), f"expected a ValueError, got {out!r}"
    assert re.search(pattern, str(out)), f"{str(out)!r} does not match {pattern!r}"


# --- class 3: memory bombs from small files -------------------------------------------------


def pcd_header(fields: str, size: str, typ: str, count: str, points: int, data: str) -> bytes:
    return (
        f"VERSION .7\nFIELDS {fields}\nSIZE {size}\nTYPE {typ}\nCOUNT {count}\n"
        f"WIDTH {points}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA {data}\n"
    ).encode()


def test_pcd_binary_compressed_with_lying_sizes(tmp_path: Path) -> None:
    # The example: ~134 bytes whose size fields claim gigabytes.
    n = 357_913_941  # 3 float fields: 4,294,967,292 bytes, just below 2**32
    raw = pcd_header("x y z", "4 4 4", "F F F", "1 1 1", n, "binary_compressed")
    raw += struct.pack("<II", 4, 12 * n) + b"\x00\x00\x00\x00"
    assert len(raw) < 200
    fails(read_bounded(write(tmp_path, "bomb.pcd", raw)), "LZF expands at most")


def test_pcd_compressed_block_longer_than_file(tmp_path: Path) -> None:
    raw = pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 1, "binary_compressed")
    raw += struct.pack("<II", 2**31, 12) + b"\x00" * 4
    fails(read_bounded(write(tmp_path, "long.pcd", raw)), "truncated")


def test_pcd_binary_huge_points_and_count(tmp_path: Path) -> None:
    raw = pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 10**15, "binary") + b"\x00" * 24
    fails(read_bounded(write(tmp_path, "points.pcd", raw)), "truncated")
    raw = pcd_header("x y z", "4 4 4", "F F F", f"1 1 {10**15}", 1, "binary") + b"\x00" * 24
    fails(read_bounded(write(tmp_path, "count.pcd", raw)), "COUNT")
    raw = pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 10**15, "ascii") + b"1 2 3\n"
    fails(read_bounded(write(tmp_path, "ascii.pcd", raw)), "truncated")


def ply(fmt: str, *elements: str) -> bytes:
    return ("ply\nformat " + fmt + " 1.0\n" + "".join(elements) + "end_header\n").encode()


VERTEX = "element vertex {}\nproperty float x\nproperty float y\nproperty float z\n"
FACE = "element face {}\nproperty list uchar int vertex_indices\n"


def test_ply_binary_counts_beyond_the_file(tmp_path: Path) -> None:
    raw = ply("binary_little_endian", VERTEX.format(10**15)) + b"\x00" * 36
    fails(read_bounded(write(tmp_path, "v.ply", raw)), "truncated")
    # A list length of 2**32 - 1 items in the first record.
    raw = ply(
        "binary_little_endian",
        VERTEX.format(3),
        "element face 1\nproperty list uint int vertex_indices\n",
    )
    raw += np.zeros(9, "<f4").tobytes() + struct.pack("<I", 2**32 - 1) + b"\x00" * 12
    fails(read_bounded(write(tmp_path, "list.ply", raw)), "truncated")


def test_ply_element_without_properties_is_not_looped_over(tmp_path: Path) -> None:
    # 10**18 records of zero bytes each: nothing to read, and nothing to loop over.
    raw = ply("binary_little_endian", "element junk 1000000000000000000\n", VERTEX.format(1))
    raw += np.ones(3, "<f4").tobytes()
    out = read_bounded(write(tmp_path, "junk.ply", raw))
    assert isinstance(out, PointCloud) and len(out) == 1


def test_ply_ascii_and_off_huge_counts(tmp_path: Path) -> None:
    raw = ply("ascii", VERTEX.format(10**15)) + b"1 2 3\n"
    fails(read_bounded(write(tmp_path, "a.ply", raw)), "truncated")
    fails(read_bounded(write(tmp_path, "a.off", b"OFF\n1000000000000 0 0\n1 2 3\n")), "truncated")


def npy_bytes(descr: str, shape: tuple[int, ...], body: bytes, fortran: bool = False) -> bytes:
    header = f"{{'descr': '{descr}', 'fortran_order': {fortran}, 'shape': {shape}, }}"
    header += " " * (-(len(header) + 11) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + body


def test_npy_header_larger_than_the_file(tmp_path: Path) -> None:
    raw = npy_bytes("<f8", (10**9, 3), b"\x00" * 48)
    assert len(raw) < 200
    fails(read_bounded(write(tmp_path, "big.npy", raw)), r"declares shape \(1000000000, 3\)")


def test_npz_member_size_lies(tmp_path: Path) -> None:
    buf = io.BytesIO()
    np.savez_compressed(buf, points=np.zeros((4, 3)))
    raw = bytearray(buf.getvalue())
    # Patch the declared uncompressed size (local header and central directory) to 4 GB.
    for sig, offset in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        at = raw.find(sig)
        raw[at + offset : at + offset + 4] = struct.pack("<I", 2**32 - 1)
    fails(read_bounded(write(tmp_path, "lie.npz", bytes(raw))), "no archive can hold")


def test_npz_reads_only_the_members_it_needs(tmp_path: Path) -> None:
    # 16 MB of zeros deflates to ~16 KB; it is never decompressed, so reading stays small.
    buf = io.BytesIO()
    np.savez_compressed(buf, points=np.ones((5, 3)), junk=np.zeros(2 << 20))
    path = write(tmp_path, "junk.npz", buf.getvalue())
    size = path.stat().st_size
    with bounded() as usage:
        cloud = read_point_cloud(path)
    assert len(cloud) == 5
    assert usage.peak_bytes < 4 << 20  # the junk member alone is 16 MB
    assert size < 1 << 20


def _npz_with_zeros(path: Path, name: str, nbytes: int) -> Path:
    """An archive of 5 points and a member ``name`` of ``nbytes`` zeros (float64, one column),
    deflated a chunk at a time (a few hundred KB on disk)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        buf = io.BytesIO()
        np.save(buf, np.ones((5, 3)))
        z.writestr("points.npy", buf.getvalue())
        with z.open(f"{name}.npy", "w", force_zip64=True) as fh:
            fh.write(npy_bytes("<f8", (nbytes // 8, 1), b""))
            chunk = bytes(8 << 20)
            for _ in range(nbytes // len(chunk)):
                fh.write(chunk)
    return path


@pytest.mark.parametrize("name", ["extra", "normals", "colors"])
def test_a_large_npz_member_that_is_not_used_is_not_decompressed(tmp_path: Path, name: str) -> None:
    # 200 MB of zeros: skipped as unused ("extra"), or refused from its header's shape
    # (normals and colors must match the points) before any of it is decompressed.
    path = _npz_with_zeros(tmp_path / f"{name}.npz", name, 200 << 20)
    assert path.stat().st_size < 1 << 20
    with bounded() as usage:
        out = expect_clean(lambda: read_point_cloud(path), allow_memory_error=False)
    assert usage.peak_bytes < 8 << 20
    if name == "extra":
        assert isinstance(out, PointCloud) and len(out) == 5
    else:
        fails(out, rf"array '{name}' has shape \(26214400, 1\), the points have \(5, 3\)")


def test_a_used_npz_member_is_decompressed_into_its_array_once() -> None:
    # 24 MB of points: the reader's peak is the array plus one chunk, not the array twice.
    pts = np.random.default_rng(0).normal(size=(1_000_000, 3))
    buf = io.BytesIO()
    np.savez_compressed(buf, points=pts)
    raw = buf.getvalue()
    with bounded() as usage:
        arrays, names = read_npz_members(raw)
    np.testing.assert_array_equal(arrays["points"], pts)
    assert names == ["points"]
    assert usage.peak_bytes < pts.nbytes + (6 << 20)


def test_npz_object_arrays_are_never_unpickled(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"

    class Exploit:
        def __reduce__(self) -> tuple[object, tuple[str]]:
            return (os.system, (f"touch {marker}",))

    buf = io.BytesIO()
    np.save(buf, np.array([Exploit()], dtype=object), allow_pickle=True)
    fails(read_bounded(write(tmp_path, "evil.npy", buf.getvalue())), "pickle")
    zbuf = io.BytesIO()
    with zipfile.ZipFile(zbuf, "w") as z:
        z.writestr("points.npy", buf.getvalue())
    fails(read_bounded(write(tmp_path, "evil.npz", zbuf.getvalue())), "pickle")
    assert not marker.exists()


def test_only_regular_files_are_read(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    fails(read_bounded(fifo), "FIFO")  # would block forever in open() or read()
    zero = tmp_path / "zero.npy"
    zero.symlink_to("/dev/zero")
    fails(read_bounded(zero), "device")  # would never end
    with bounded(), pytest.raises(ValueError, match="FIFO"):
        read_open3d_feature(fifo)
    with pytest.raises(FileNotFoundError):
        read_point_cloud(tmp_path / "missing.ply")
    with pytest.raises(FileNotFoundError):
        read_point_cloud(tmp_path / "junk.ply" / "below-a-file.ply")


# --- class 4: integers that do not fit their type -------------------------------------------


def test_ply_ascii_integers_that_do_not_fit(tmp_path: Path) -> None:
    colour = (
        "element vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
    )
    raw = ply("ascii", colour) + b"0 0 0 1 2 3\n1 1 1 300 2 3\n"
    out = read_bounded(write(tmp_path, "c.ply", raw))
    fails(out, r"element 'vertex', property 'red', line 12: 300 is outside the range of uint8")
    raw = (
        ply("ascii", VERTEX.format(3), FACE.format(1))
        + b"0 0 0\n1 0 0\n0 1 0\n3 0 1 1099511627776\n"
    )
    fails(read_bounded(write(tmp_path, "big.ply", raw)), r"'face'.*line 13.*int32")
    raw = ply("ascii", VERTEX.format(3), FACE.format(1)) + b"0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n"
    fails(read_bounded(write(tmp_path, "range.ply", raw)), r"'face', line 13: vertex index 7")
    raw = ply("ascii", VERTEX.format(3), FACE.format(1)) + b"0 0 0\n1 0 0\n0 1 0\n3 0 1 nan\n"
    fails(read_bounded(write(tmp_path, "nan.ply", raw)), r"line 13: nan is not a finite number")
    raw = ply("ascii", VERTEX.format(3), FACE.format(1)) + b"0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n"
    fails(read_bounded(write(tmp_path, "frac.ply", raw)), r"line 13: 1.5 is not a whole number")
    raw = ply("ascii", VERTEX.format(3), FACE.format(1)) + b"0 0 0\n1 0 0\n0 1 0\n259 0 1 2\n"
    fails(read_bounded(write(tmp_path, "count.ply", raw)), r"line 13")


def test_binary_ply_face_index_out_of_range_names_the_record(tmp_path: Path) -> None:
    raw = ply("binary_little_endian", VERTEX.format(3), FACE.format(2))
    raw += np.eye(3, dtype="<f4").tobytes()
    raw += b"\x03" + np.array([0, 1, 2], "<i4").tobytes()
    raw += b"\x03" + np.array([0, 1, -5], "<i4").tobytes()
    fails(read_bounded(write(tmp_path, "f.ply", raw)), r"record 1: vertex index -5")


def test_pcd_ascii_integer_fields(tmp_path: Path) -> None:
    head = pcd_header("x y z label", "4 4 4 1", "F F F U", "1 1 1 1", 2, "ascii")
    out = read_bounded(write(tmp_path, "l.pcd", head + b"0 0 0 1\n1 1 1 300\n"))
    fails(out, r"field 'label' on line 12 holds 300.*uint8")
    out = read_bounded(write(tmp_path, "n.pcd", head + b"0 0 0 nan\n1 1 1 3\n"))
    fails(out, r"field 'label' on line 11 holds nan")


def test_off_face_indices(tmp_path: Path) -> None:
    base = b"OFF\n# a comment\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n"
    fails(read_bounded(write(tmp_path, "a.off", base + b"3 0 1 3\n")), r"line 7: vertex index 3")
    huge = base + b"3 0 1 99999999999999999999999\n"
    fails(read_bounded(write(tmp_path, "b.off", huge)), r"line 7")
    mixed = base.replace(b"3 1 0", b"3 2 0") + b"3 0 1 2\n4 0 1 2 -1\n"
    fails(read_bounded(write(tmp_path, "c.off", mixed)), r"line 8: vertex index -1")


# --- generated malformed files ---------------------------------------------------------------

COUNTS = st.one_of(
    st.integers(0, 12),
    st.integers(-3, 2**70),
    st.sampled_from([2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**63 - 1, 2**64, 10**18]),
)
NUMBER_WORDS = st.one_of(
    st.integers(-(2**70), 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True, width=64).map(repr),
    st.sampled_from(["nan", "-nan", "inf", "300", "256", "-1", "0", "3", "1e400", "x", "1_0"]),
)
TEXT_ROWS = st.lists(st.lists(NUMBER_WORDS, max_size=9).map(" ".join), max_size=24).map(
    lambda rows: ("\n".join(rows) + "\n").encode()
)
PLY_TYPES = st.sampled_from(
    ["char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8", "uint32", "x"]
)
PLY_NAMES = st.sampled_from(
    ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "vertex_indices", "vertex_index"]
)


@st.composite
def ply_files(draw: st.DrawFn) -> bytes:
    fmt = draw(st.sampled_from(["ascii", "binary_little_endian", "binary_big_endian"]))
    head = ["ply", f"format {fmt} 1.0"]
    names = draw(st.lists(st.sampled_from(["vertex", "face", "range_grid", "edge"]), max_size=3))
    for name in names:
        head.append(f"element {name} {draw(COUNTS)}")
        for _ in range(draw(st.integers(0, 5))):
            if draw(st.booleans()):
                head.append(f"property {draw(PLY_TYPES)} {draw(PLY_NAMES)}")
            else:
                head.append(f"property list {draw(PLY_TYPES)} {draw(PLY_TYPES)} {draw(PLY_NAMES)}")
    head.append("end_header")
    body = draw(TEXT_ROWS) if fmt == "ascii" else draw(st.binary(max_size=1024))
    return ("\n".join(head) + "\n").encode() + body


PCD_FIELDS = st.sampled_from(["x", "y", "z", "normal_x", "normal_y", "normal_z", "rgb", "label"])


@st.composite
def pcd_files(draw: st.DrawFn) -> bytes:
    fields = draw(st.lists(PCD_FIELDS, min_size=1, max_size=7))
    size = [str(draw(st.sampled_from([1, 2, 4, 8, 3]))) for _ in fields]
    typ = [draw(st.sampled_from(["F", "U", "I", "Q"])) for _ in fields]
    count = [str(draw(st.one_of(st.just(1), COUNTS))) for _ in fields]
    points = draw(COUNTS)
    data = draw(st.sampled_from(["ascii", "binary", "binary_compressed", "zip"]))
    record = sum(int(a) * int(c) for a, c in zip(size, count, strict=True))
    raw = pcd_header(" ".join(fields), " ".join(size), " ".join(typ), " ".join(count), 0, data)
    raw = raw.replace(b"WIDTH 0", f"WIDTH {points}".encode())
    raw = raw.replace(b"POINTS 0", f"POINTS {draw(st.one_of(st.just(points), COUNTS))}".encode())
    if data == "ascii":
        return raw + draw(TEXT_ROWS)
    if data == "binary_compressed":
        block = draw(st.binary(max_size=1024))
        # Often the sizes a reader would believe: the raw size the header implies (a lie
        # about the block only), and the block's true length.
        unpacked = draw(st.one_of(st.just(points * record), st.integers(0, 2**32 - 1)))
        packed = draw(st.one_of(st.just(len(block)), st.integers(0, 2**32 - 1)))
        sizes = struct.pack("<II", packed % 2**32, unpacked % 2**32)
        return raw + sizes + block
    return raw + draw(st.binary(max_size=1024))


@st.composite
def off_files(draw: st.DrawFn) -> bytes:
    keyword = draw(st.sampled_from(["OFF", "COFF", "NOFF", "CNOFF", "OFF BINARY", "XOFF"]))
    counts = f"{draw(COUNTS)} {draw(COUNTS)} {draw(COUNTS)}"
    glued = draw(st.booleans())
    head = f"{keyword}{counts}\n" if glued else f"{keyword}\n{counts}\n"
    return head.encode() + draw(TEXT_ROWS)


DESCRS = st.sampled_from(["<f8", "<f4", ">f8", "|u1", "<i8", "|b1", "<c16", "|O", "<U3", "|V8"])
SHAPES = st.lists(COUNTS, max_size=3).map(tuple)


@st.composite
def npy_files(draw: st.DrawFn) -> bytes:
    return npy_bytes(
        draw(DESCRS), draw(SHAPES), draw(st.binary(max_size=1024)), draw(st.booleans())
    )


@st.composite
def npz_files(draw: st.DrawFn) -> bytes:
    buf = io.BytesIO()
    method = draw(st.sampled_from([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED]))
    with zipfile.ZipFile(buf, "w", compression=method) as z:
        for name in draw(
            st.lists(st.sampled_from(["points", "normals", "colors", "x"]), max_size=3, unique=True)
        ):
            if draw(st.booleans()):
                body = np.ones((draw(st.integers(0, 6)), draw(st.sampled_from([3, 6, 2]))))
                payload = io.BytesIO()
                np.save(payload, body.astype(draw(st.sampled_from(["<f8", "<f4", "|u1"]))))
                z.writestr(f"{name}.npy", payload.getvalue())
            else:
                z.writestr(f"{name}.npy", draw(npy_files()))
    return draw(mutated(buf.getvalue()))


def mutated(raw: bytes) -> st.SearchStrategy[bytes]:
    """Byte-level damage to a valid file: truncation, flipped bytes, numbers replaced by huge
    or negative ones, junk inserted."""

    @st.composite
    def damage(draw: st.DrawFn) -> bytes:
        out = bytearray(raw)
        for _ in range(draw(st.integers(1, 4))):
            op = draw(st.sampled_from(["truncate", "flip", "number", "insert"]))
            if not out:
                break
            at = draw(st.integers(0, len(out) - 1))
            if op == "truncate":
                del out[at:]
            elif op == "flip":
                out[at] = draw(st.integers(0, 255))
            elif op == "insert":
                out[at:at] = draw(st.binary(min_size=1, max_size=16))
            else:
                digits = [m.span() for m in re.finditer(rb"\d+", bytes(out))]
                if digits:
                    lo, hi = digits[draw(st.integers(0, len(digits) - 1))]
                    out[lo:hi] = str(draw(COUNTS)).encode()
        return bytes(out)

    return damage()


def _lzf_literals(data: bytes) -> bytes:
    """A valid LZF stream of literal runs only (what a PCD writer without matches emits)."""
    out = bytearray()
    for i in range(0, len(data), 32):
        chunk = data[i : i + 32]
        out += bytes([len(chunk) - 1]) + chunk
    return bytes(out)


def _valid_files() -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(6, 3))
    files: dict[str, bytes] = {}
    tri = "3 0 1 2\n3 0 2 3\n4 1 2 4 5\n"
    verts = "".join(f"{x:.4f} {y:.4f} {z:.4f} 10 200 30\n" for x, y, z in pts)
    colour = VERTEX.format(6) + "property uchar red\nproperty uchar green\nproperty uchar blue\n"
    files["mesh_ascii.ply"] = ply("ascii", colour, FACE.format(3)) + (verts + tri).encode()
    record = np.zeros(6, [("p", "<f4", 3), ("c", "u1", 3)])
    record["p"], record["c"] = pts, 128
    faces = b"".join(
        bytes([len(f)]) + np.array(f, "<i4").tobytes() for f in ([0, 1, 2], [0, 2, 3], [1, 2, 4, 5])
    )
    files["mesh_binary.ply"] = (
        ply("binary_little_endian", colour, FACE.format(3)) + record.tobytes() + faces
    )
    head = pcd_header("x y z rgb", "4 4 4 4", "F F F U", "1 1 1 1", 6, "ascii")
    files["cloud_ascii.pcd"] = (
        head + "".join(f"{x:.4f} {y:.4f} {z:.4f} 4278190080\n" for x, y, z in pts).encode()
    )
    binary = np.zeros(6, [("p", "<f4", 3), ("c", "<u4")])
    binary["p"] = pts
    head = pcd_header("x y z rgb", "4 4 4 4", "F F F U", "1 1 1 1", 6, "binary")
    files["cloud_binary.pcd"] = head + binary.tobytes()
    soa = b"".join(pts[:, i].astype("<f4").tobytes() for i in range(3))
    block = _lzf_literals(soa)
    head = pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 6, "binary_compressed")
    files["cloud_compressed.pcd"] = head + struct.pack("<II", len(block), len(soa)) + block
    files["mesh.off"] = ("OFF\n6 3 0\n" + verts.replace(" 10 200 30", "") + tri).encode()
    files["cloud.xyz"] = "".join(f"{x} {y} {z}\n" for x, y, z in pts).encode()
    buf = io.BytesIO()
    np.save(buf, pts)
    files["cloud.npy"] = buf.getvalue()
    buf = io.BytesIO()
    np.savez_compressed(buf, points=pts, normals=pts, colors=np.full((6, 3), 7, np.uint8))
    files["cloud.npz"] = buf.getvalue()
    return files


VALID = _valid_files()


def test_the_valid_seeds_read(tmp_path: Path) -> None:
    """The files mutated below are readable before they are damaged."""
    for name, raw in VALID.items():
        out = read_bounded(write(tmp_path, name, raw))
        assert isinstance(out, PointCloud), f"{name}: {out}"


GENERATED = {
    ".ply": ply_files(),
    ".pcd": pcd_files(),
    ".off": off_files(),
    ".xyz": TEXT_ROWS,
    ".npy": npy_files(),
    ".npz": npz_files(),
}


def _check_generated(tmp: Path, suffix: str, raw: bytes, key: str) -> None:
    CASES[f"files:{key}"] += 1
    path = write(tmp, f"case{suffix}", raw)
    read_bounded(path, n_samples=500)
    assert path.read_bytes() == raw  # a reader never writes


@pytest.mark.parametrize("suffix", sorted(GENERATED))
def test_generated_files(suffix: str, tmp_path_factory: pytest.TempPathFactory) -> None:
    tmp = tmp_path_factory.mktemp("generated")

    @SETTINGS
    @given(raw=GENERATED[suffix])
    def run(raw: bytes) -> None:
        _check_generated(tmp, suffix, raw, f"generated{suffix}")

    run()


@pytest.mark.parametrize("name", sorted(VALID))
def test_damaged_files(name: str, tmp_path_factory: pytest.TempPathFactory) -> None:
    tmp = tmp_path_factory.mktemp("damaged")
    suffix = Path(name).suffix

    @SETTINGS
    @given(raw=mutated(VALID[name]))
    def run(raw: bytes) -> None:
        _check_generated(tmp, suffix, raw, f"damaged:{name}")

    run()
