"""Shapes to register: the packaged bunny, procedural meshes, mesh files and ModelNet40.

Why: the synthetic protocol (SPEC section 3) starts from a unit-sphere-normalised 2048-point
cloud of one object. The paper draws it from ModelNet40's ``ply_hdf5_2048`` release; this
module offers that (with h5py) and, so that nothing must be downloaded, the packaged Stanford
bunny (numpy only), a few procedural shapes, and any mesh file :func:`pointclm.io.read_mesh`
reads (PLY, OFF and numpy arrays natively; OBJ and STL with trimesh).

Clouds are sampled uniformly by surface area with :func:`pointclm.io.mesh.sample_mesh`, the
project's one surface sampler (area-weighted triangle choice, then uniform barycentric
coordinates), from a seeded :class:`numpy.random.Generator`, then centred on their centroid
and scaled so that the largest norm is 1.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import PathNotFoundError
from ..io.mesh import sample_mesh
from ..io.reader import MESH_SUFFIXES, read_mesh
from .procedural import PROCEDURAL_FAMILIES, PROCEDURAL_SHAPES, is_procedural, procedural_mesh

__all__ = [
    "MESH_SUFFIXES",
    "available_shapes",
    "load_mesh",
    "load_shape",
    "modelnet40_shapes",
    "normalize_unit_sphere",
    "sample_surface",
]

_DATA = Path(__file__).resolve().parent / "data"
_BUNNY = _DATA / "bunny_res4.npz"

#: Clean names for the files of the project's data folder (``data/SOURCES.md``).
_KNOWN_FILES: dict[str, str] = {
    "stanford/bunny/reconstruction/bun_zipper_res2.ply": "stanford/bunny-res2",
    "stanford/bunny/reconstruction/bun_zipper_res3.ply": "stanford/bunny-res3",
    "stanford/bunny/reconstruction/bun_zipper_res4.ply": "stanford/bunny-res4",
    "stanford/dragon/dragon_spica_21790v.ply": "stanford/dragon",
    "stanford/happy/happy_vrip_res3.ply": "stanford/happy",
    "stanford/armadillo/Armadillo_38294v.ply": "stanford/armadillo",
    "modelnet/bathtub_0154.ply": "modelnet/bathtub",
    "modelnet/bed_fmr.off": "modelnet/bed",
    "stanford/bunny/data/bun000.ply": "stanford/bunny-scan000",
    "stanford/bunny/data/bun045.ply": "stanford/bunny-scan045",
    "stanford/bunny/data/bun090.ply": "stanford/bunny-scan090",
    "stanford/bunny/data/bun315.ply": "stanford/bunny-scan315",
}
#: Suffixes :func:`available_shapes` looks for in a data folder (arrays are not listed: a
#: ``.npy`` there is as likely a pose or a feature file as a cloud).
_LISTED_SUFFIXES: tuple[str, ...] = (".ply", ".off", ".obj", ".stl")

Rng = np.random.Generator | int | None
PathLike = str | os.PathLike[str]


def normalize_unit_sphere(points: np.ndarray) -> np.ndarray:
    """Centre a cloud on its centroid and scale it so that its largest norm is 1.

    Parameters
    ----------
    points : numpy.ndarray
        (N, 3) cloud.

    Returns
    -------
    numpy.ndarray
        (N, 3) float64 copy.

    Raises
    ------
    ValueError
        If the cloud is empty, not (N, 3), not finite, or a single point.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"expected a non-empty (N, 3) cloud, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("cloud has non-finite coordinates")
    pts = pts - pts.mean(axis=0)
    scale = np.linalg.norm(pts, axis=1).max()
    if scale <= 0:
        raise ValueError("cloud is a single point; it cannot be normalised")
    return pts / scale


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, n_points: int, rng: Rng = 0
) -> np.ndarray:
    """Sample points uniformly by area on a triangle mesh.

    The points of :func:`pointclm.io.mesh.sample_mesh` (the one sampler, so a seed gives the
    same points through :mod:`pointclm.io` and here); triangles touching a non-finite vertex
    get no samples.

    Parameters
    ----------
    vertices : numpy.ndarray
        (V, 3) vertex positions.
    faces : numpy.ndarray
        (F, 3) triangle vertex indices.
    n_points : int
        Number of samples.
    rng : numpy.random.Generator or int or None
        Generator or seed (``None``: fresh entropy).

    Returns
    -------
    numpy.ndarray
        (n_points, 3) float64 samples (not normalised).

    Raises
    ------
    ValueError
        If the mesh has no triangle of positive, finite area, indices out of range, or
        ``n_points`` is not a positive int.
    """
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"expected (F, 3) triangles, got shape {f.shape}")
    if f.min() < 0 or f.max() >= len(vertices):
        raise ValueError("face indices out of range")
    return sample_mesh(vertices, f, n_points, np.random.default_rng(rng)).points


def _sample_points(points: np.ndarray, n_points: int, rng: np.random.Generator) -> np.ndarray:
    """Random subset of a point-only cloud (with replacement only if it is too small)."""
    replace = len(points) < n_points
    return points[rng.choice(len(points), size=n_points, replace=replace)]


def bunny_mesh() -> tuple[np.ndarray, np.ndarray]:
    with np.load(_BUNNY) as data:
        return data["vertices"], data["faces"]


def load_mesh(path: PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a mesh or point-cloud file (:func:`pointclm.io.read_mesh`).

    ``.npy`` holds an (N, 3) cloud; ``.npz`` holds ``vertices`` and optionally ``faces`` (the
    packaged format); ``.ply``/``.off`` are read by :mod:`pointclm.io`, ``.obj``/``.stl``
    with trimesh (lazily imported, ``pip install pointclm[io]``), scenes being merged into
    one mesh.

    Parameters
    ----------
    path : str or os.PathLike
        File to read.

    Returns
    -------
    vertices : numpy.ndarray
        (V, 3) float64.
    faces : numpy.ndarray or None
        (F, 3) int64 triangles, or ``None`` for a point-only file.

    Raises
    ------
    PathNotFoundError
        If the file is missing (a FileNotFoundError and a ValueError).
    ValueError
        If the file is of an unknown type, unreadable or empty; the message names it.
    ImportError
        If trimesh is needed and not installed.
    """
    mesh = read_mesh(path)
    return mesh.vertices, mesh.triangles


def _data_files(data_dir: PathLike) -> dict[str, Path]:
    """Map clean names to the mesh files found under ``data_dir``."""
    root = Path(data_dir)
    if not root.is_dir():
        raise PathNotFoundError(f"{root}: data folder does not exist")
    found: dict[str, Path] = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root).as_posix()
        if p.suffix.lower() not in _LISTED_SUFFIXES or not p.is_file():
            continue
        if any(part.startswith(".") for part in p.relative_to(root).parts):
            continue
        name = _KNOWN_FILES.get(rel, rel[: -len(p.suffix)])
        found.setdefault(name, p)
    return found


def available_shapes(data_dir: PathLike | None = None) -> list[str]:
    """Names :func:`load_shape` accepts.

    Parameters
    ----------
    data_dir : str or os.PathLike, optional
        A user-supplied data folder (for this project: ``../shared/data``). Mesh and point
        files under it (``.ply``, ``.off``, ``.obj``, ``.stl``) are listed too; the files of
        ``data/SOURCES.md`` get clean names such as ``"stanford/dragon"`` or
        ``"modelnet/bed"``, others their relative path without suffix.

    Returns
    -------
    list of str
        ``"bunny"``, the procedural shapes, then the data folder's shapes (sorted).
    """
    names = ["bunny", *PROCEDURAL_SHAPES]
    if data_dir is not None:
        names += sorted(_data_files(data_dir))
    return names


def load_shape(
    name_or_path: PathLike,
    n_points: int = 2048,
    rng: Rng = 0,
    *,
    data_dir: PathLike | None = None,
) -> np.ndarray:
    """Sample a unit-sphere-normalised cloud from a named shape or a file.

    Parameters
    ----------
    name_or_path : str or os.PathLike
        ``"bunny"`` (packaged, numpy only), a procedural shape (``"torus"``, ``"box"``,
        ``"cylinder"``, ``"cone"``, ``"capsule"``, ``"helix-tube"``, or a random one of a
        family such as ``"superquadric-17"``: :func:`pointclm.datasets.procedural_mesh`), a
        name from :func:`available_shapes` ``(data_dir)``, or a mesh/point file path.
    n_points : int, default 2048
        Number of points.
    rng : numpy.random.Generator or int or None, default 0
        Generator or seed of the sampling (``None``: fresh entropy).
    data_dir : str or os.PathLike, optional
        Data folder in which to resolve names such as ``"stanford/dragon"``.

    Returns
    -------
    numpy.ndarray
        (n_points, 3) float64, centroid at the origin, largest norm 1. Meshes are sampled by
        area; point-only files by a random subset of their points (with replacement only when
        they hold fewer than ``n_points``).

    Raises
    ------
    PathNotFoundError
        A file that does not exist (a name with a file suffix, a data folder that does not
        exist); it is a FileNotFoundError and a ValueError.
    ValueError
        Unknown name or unreadable file (the message names it).
    ImportError
        A mesh file needs trimesh and it is not installed.
    """
    if n_points < 1:
        raise ValueError(f"n_points must be positive, got {n_points}")
    gen = np.random.default_rng(rng)
    key = os.fspath(name_or_path)
    if key == "bunny":
        verts, faces = bunny_mesh()
        return normalize_unit_sphere(sample_surface(verts, faces, n_points, gen))
    if is_procedural(key):
        verts, faces = procedural_mesh(key)
        return normalize_unit_sphere(sample_surface(verts, faces, n_points, gen))
    path = _shape_file(key, data_dir)
    try:
        return normalize_unit_sphere(_file_samples(path, n_points, gen))
    except ValueError as err:
        if str(err).startswith(str(path)):
            raise
        raise ValueError(f"{path}: {err}") from err


def _shape_file(key: str, data_dir: PathLike | None) -> Path:
    """The file a shape name or path names (a data-folder name resolved in ``data_dir``)."""
    path = Path(key)
    if data_dir is not None and not path.is_file():
        files = _data_files(data_dir)
        if key in files:
            path = files[key]
    if not path.is_file():
        if not path.suffix and key.partition("-")[0] in PROCEDURAL_FAMILIES:
            procedural_mesh(key)  # a malformed family name: raises, saying what a valid one is
        hint = "" if data_dir is not None else " (pass data_dir= to resolve data-folder names)"
        # a name with a file suffix was meant as a file: a missing file, not an unknown name
        error = PathNotFoundError if path.suffix else ValueError
        raise error(
            f"{key!r} is neither a known shape nor an existing file{hint}; known shapes: "
            f"{', '.join(available_shapes(data_dir))}, and random ones named '<family>-<seed>' "
            f"with <family> one of {', '.join(PROCEDURAL_FAMILIES)} (e.g. 'superquadric-17')"
        )
    return path


def _file_samples(path: Path, n_points: int, gen: np.random.Generator) -> np.ndarray:
    """A mesh file sampled by area; a point-only file by a random subset of its points."""
    file_verts, file_faces = load_mesh(path)
    if file_faces is None:
        return _sample_points(file_verts, n_points, gen)
    return sample_surface(file_verts, file_faces, n_points, gen)


def modelnet40_shapes(
    folder: PathLike, split: str = "test", *, with_labels: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Read the clouds of ModelNet40's ``modelnet40_ply_hdf5_2048`` release.

    This is the data the paper's synthetic benchmark is built from. The files are listed by
    ``{split}_files.txt`` when present, else found as ``ply_data_{split}*.h5`` in numeric order.

    Parameters
    ----------
    folder : str or os.PathLike
        The unpacked ``modelnet40_ply_hdf5_2048`` folder.
    split : {"test", "train"}
        Which split.
    with_labels : bool, default False
        Also return the class labels.

    Returns
    -------
    clouds : numpy.ndarray
        (S, 2048, 3) float64 clouds in file order.
    labels : numpy.ndarray
        (S,) int64 class indices, only if ``with_labels``.

    Raises
    ------
    ImportError
        If h5py is not installed.
    PathNotFoundError
        If the folder holds no file of the split, or one it lists is missing (a
        FileNotFoundError and a ValueError).
    ValueError
        If a file is malformed.
    """
    # The files first: a missing folder is reported as missing whether or not h5py is there.
    files = _modelnet_files(Path(folder), split)
    try:
        import h5py
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError("reading ModelNet40 HDF5 files needs h5py: pip install h5py") from err
    clouds, labels = [], []
    for f in files:
        try:
            with h5py.File(f, "r") as h5:
                data = np.asarray(h5["data"][:], dtype=np.float64)
                label = np.asarray(h5["label"][:], dtype=np.int64).reshape(-1)
        except Exception as err:  # noqa: BLE001 - any reader failure becomes a ValueError
            raise ValueError(f"{f}: cannot read it ({type(err).__name__}: {err})") from err
        if data.ndim != 3 or data.shape[2] != 3 or len(label) != len(data):
            raise ValueError(f"{f}: expected data (n, P, 3) and n labels, got {data.shape}")
        clouds.append(data)
        labels.append(label)
    out = np.concatenate(clouds)
    return (out, np.concatenate(labels)) if with_labels else out


def _modelnet_files(root: Path, split: str) -> list[Path]:
    if split not in ("train", "test"):
        raise ValueError(f"split must be 'train' or 'test', got {split!r}")
    listing = root / f"{split}_files.txt"
    if listing.is_file():
        names = [ln.strip() for ln in listing.read_text().splitlines() if ln.strip()]
        files = [root / Path(n).name for n in names]
    else:
        files = sorted(
            root.glob(f"ply_data_{split}*.h5"),
            key=lambda p: int("".join(ch for ch in p.stem if ch.isdigit()) or 0),
        )
    if not files:
        raise PathNotFoundError(
            f"{root}: no ply_data_{split}*.h5 files (is it modelnet40_ply_hdf5_2048?)"
        )
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise PathNotFoundError(f"{root}: files listed in {split}_files.txt are missing: {missing}")
    return files
