"""Procedural triangle meshes that need nothing but numpy.

Why: tests, examples and benchmarks must run without any data download, and a single shape
(the packaged bunny) hides shape-dependent bugs. Each mesh is deliberately given no continuous
symmetry (a bulging torus, an elliptic cylinder, an oblique cone, ...) so that descriptor-based
matching on it stays meaningful; correspondence-based registration does not care either way.

Besides the six fixed meshes of :data:`PROCEDURAL_SHAPES`, three families of random shapes
(:data:`PROCEDURAL_FAMILIES`) give as many shapes as training wants, named
``"<family>-<seed>"`` (``"superquadric-17"``, ``"blend-3"``, ``"extrusion-250"``) so that every
path that takes a model name takes them. Why: a learned correspondence embedding trained on a
handful of shapes learns the shapes instead of consistency. Each family shape is deformed by a
random taper, twist, bend and smooth bumps so that it has no symmetry: a symmetric shape's
mirrored descriptor matches are geometrically consistent yet labelled wrong in training.

The meshes are in arbitrary units; :func:`pointclm.datasets.load_shape` samples them by area and
normalises the samples to the unit sphere.
"""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np

from .procedural_shapes import (
    Mesh,
    _box,
    _capsule,
    _cone,
    _cylinder,
    _grid,
    _helix_tube,
    _merge,
    _ring,
    _torus,
)

__all__ = [
    "PROCEDURAL_FAMILIES",
    "PROCEDURAL_SHAPES",
    "is_procedural",
    "procedural_family_names",
    "procedural_mesh",
]


# --- random families ----------------------------------------------------------------------

#: Families of random shapes; ``"<family>-<seed>"`` names one (see :func:`procedural_mesh`).
PROCEDURAL_FAMILIES: tuple[str, ...] = ("superquadric", "blend", "extrusion")

# Mixed into every family's seed so that "blend-3" and "extrusion-3" draw unrelated numbers.
# Changing a key or the salt changes every family mesh (and any training run built on them).
_FAMILY_KEYS = {"superquadric": 1, "blend": 2, "extrusion": 3}
_SALT = 16
_NAME_SEEDS = 1_000_000  # procedural_family_names draws seeds below this: short names
# Canonical decimal only: "blend-07" and "blend-7" would be one mesh under two names, and
# training configs keep train and validation shapes apart by name.
_SEED = re.compile(r"0|[1-9][0-9]*", re.ASCII)


def _family_rng(family: str, seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([_SALT, _FAMILY_KEYS[family], seed]))


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation, from a random unit quaternion (no LAPACK call, so the
    matrix does not depend on the BLAS build)."""
    w, x, y, z = (q := rng.normal(size=4)) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _cube_sphere(n: int) -> Mesh:
    """Points on the six faces of the cube [-1, 1]^3, an ``n x n`` grid on each, spaced
    equiangularly: projected radially they cover all directions evenly and have no poles
    (a latitude-longitude grid crowds its poles)."""
    t = np.tan(np.linspace(-np.pi / 4, np.pi / 4, n))
    meshes = []
    for axis in range(3):
        for sign in (-1.0, 1.0):

            def fn(
                u: np.ndarray, v: np.ndarray, axis: int = axis, sign: float = sign
            ) -> np.ndarray:
                cols = [u, v] if sign > 0 else [v, u]  # keep the faces wound outwards
                cols.insert(axis, np.full_like(u, sign))
                return np.stack(cols, -1)

            meshes.append(_grid(fn, t, t, False, False))
    return _merge(*meshes)


def _sq_ratio(p: np.ndarray, axes: np.ndarray, e1: float, e2: float) -> np.ndarray:
    """Radial ratio of points to the superquadric surface: < 1 inside, 1 on it (the inside-
    outside function raised to ``e1 / 2``, homogeneous of degree 1)."""
    a = np.abs(p / axes)
    f = (a[:, 0] ** (2 / e2) + a[:, 1] ** (2 / e2)) ** (e2 / e1) + a[:, 2] ** (2 / e1)
    return np.asarray(f ** (e1 / 2))


def _superquadric(n: int, axes: np.ndarray, e1: float, e2: float) -> Mesh:
    """A superquadric meshed from a cube-sphere stretched by its axes (so an elongated one is
    not meshed coarsely along its length)."""
    cube, faces = _cube_sphere(n)
    d = cube * axes
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d / _sq_ratio(d, axes, e1, e2)[:, None], faces


def _signed(rng: np.random.Generator, lo: float, hi: float, size: int) -> np.ndarray:
    """Magnitudes in ``[lo, hi]`` with random signs: a deformation that must break a symmetry
    is never drawn near zero."""
    return np.asarray(rng.uniform(lo, hi, size) * rng.choice([-1.0, 1.0], size))


def _deform(verts: np.ndarray, rng: np.random.Generator, amount: float = 1.0) -> np.ndarray:
    """Random taper, twist and bend along z, then smooth radial bumps, on the shape scaled to
    unit size. Together the first three break every symmetry of a box-like shape with
    unequal axes (a taper breaks the mirror through z = 0, the half-turns about x and y and
    the point reflection; a bend the mirrors through the z axis and the half-turn about it;
    a twist every mirror), and the bumps, centred at random surface points, break those of
    other shapes. ``amount`` scales the first three; none is drawn near zero."""
    v = verts - verts.mean(axis=0)
    v /= np.linalg.norm(v, axis=1).max()
    x, y, z = v.T
    tx, ty = amount * _signed(rng, 0.15, 0.5, 2)
    x, y = x * (1 + tx * z), y * (1 + ty * z)
    ang = amount * _signed(rng, 0.4, 1.2, 1) * z
    x, y = x * np.cos(ang) - y * np.sin(ang), x * np.sin(ang) + y * np.cos(ang)
    bx, by = amount * _signed(rng, 0.15, 0.5, 2)
    v = np.stack([x + bx * z * z, y + by * z * z, z], 1)
    k = int(rng.integers(5, 9))
    centres = v[rng.integers(len(v), size=k)]
    sigma = rng.uniform(0.12, 0.3, k)
    height = _signed(rng, 0.1, 0.25, k)
    d2 = ((v[:, None, :] - centres[None]) ** 2).sum(-1)
    bump = np.exp(-d2 / (2 * sigma**2)) @ height
    radial = v - v.mean(axis=0)
    radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-9)
    return np.asarray(v + bump[:, None] * radial)


def _finish(verts: np.ndarray, faces: np.ndarray) -> Mesh:
    """Drop zero-area triangles (grid rows that meet in one point) and unused vertices, and
    centre the mesh with its largest norm 1."""
    a, b, c = (verts[faces[:, i]] for i in range(3))
    area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    faces = faces[area > 1e-9 * area.max()]
    used, inverse = np.unique(faces, return_inverse=True)
    v = verts[used] - verts[used].mean(axis=0)
    v /= np.linalg.norm(v, axis=1).max()
    return v.astype(np.float64), inverse.reshape(-1, 3).astype(np.int32)


def _superquadric_shape(rng: np.random.Generator) -> Mesh:
    e1, e2 = rng.uniform(0.3, 2.5, 2)
    # Unequal axes: equal ones would leave a (near-)continuous symmetry to the deformation.
    axes = rng.permutation([1.0, rng.uniform(0.68, 0.82), rng.uniform(0.4, 0.55)])
    verts, faces = _superquadric(19, axes, e1, e2)
    return _finish(_deform(verts, rng), faces)


_PART_KINDS = ("ellipsoid", "box", "cylinder", "cone", "torus")
# Superquadric exponents (e1 along z, e2 around it) of the blend's parts: low ones give near-
# sharp edges and flat faces, which descriptors need as much as curved ones.
_PART_EXPONENTS = {
    "ellipsoid": ((0.8, 1.2), (0.8, 1.2)),
    "box": ((0.1, 0.3), (0.1, 0.3)),
    "cylinder": ((0.1, 0.3), (0.8, 1.2)),
    "cone": ((0.1, 0.3), (0.8, 1.2)),
}

Inside = Callable[[np.ndarray], np.ndarray]


def _torus_part(rng: np.random.Generator, size: float) -> tuple[Mesh, Inside, np.ndarray]:
    r1, r2 = size * rng.uniform(0.2, 0.45, 2)

    def fn(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        ring = size + r1 * np.cos(v)
        return np.stack([ring * np.cos(u), ring * np.sin(u), r2 * np.sin(v)], -1)

    def inside(p: np.ndarray) -> np.ndarray:
        rho = np.hypot(p[:, 0], p[:, 1])
        return np.asarray(((rho - size) / r1) ** 2 + (p[:, 2] / r2) ** 2 < 1)

    # anchored on its tube, not at its centre (the hole): a torus placed by its centre on
    # another part could ring it without touching
    return _grid(fn, _ring(40), _ring(16), True, True), inside, np.array([size, 0.0, 0.0])


def _part(rng: np.random.Generator, kind: str, size: float) -> tuple[Mesh, Inside, np.ndarray]:
    """One part of a blend in its own frame: its mesh, its inside test, and the point that is
    placed on the parts before it."""
    if kind == "torus":
        return _torus_part(rng, size)
    (lo1, hi1), (lo2, hi2) = _PART_EXPONENTS[kind]
    e1, e2 = rng.uniform(lo1, hi1), rng.uniform(lo2, hi2)
    axes = size * rng.uniform(0.4, 1.0, 3)
    taper = rng.uniform(0.6, 0.9) if kind == "cone" else 0.0

    def shrink(p: np.ndarray) -> np.ndarray:
        s = np.maximum(1 - taper * (p[:, 2] / axes[2] + 1) / 2, 1e-3)
        return np.stack([s, s, np.ones_like(s)], 1)

    verts, faces = _superquadric(10, axes, e1, e2)

    def inside(p: np.ndarray) -> np.ndarray:
        return np.asarray(_sq_ratio(p / shrink(p), axes, e1, e2) < 1)

    return (verts * shrink(verts), faces), inside, np.zeros(3)


def _blend_shape(rng: np.random.Generator) -> Mesh:
    """2-4 random parts, each placed on a point of an earlier one so that the union is one
    object; triangles inside another part are dropped (the union's surface, roughly: a
    triangle goes by its centroid)."""
    placed: list[tuple[np.ndarray, np.ndarray, Inside, np.ndarray, np.ndarray]] = []
    for i in range(int(rng.integers(2, 5))):
        kind = _PART_KINDS[int(rng.integers(len(_PART_KINDS)))]
        size = rng.uniform(0.6, 1.0) if i == 0 else rng.uniform(0.3, 0.7)
        (verts, faces), inside, anchor = _part(rng, kind, size)
        rot = _random_rotation(rng)
        at = np.zeros(3)
        if placed:
            earlier = placed[int(rng.integers(len(placed)))][0]
            at = earlier[int(rng.integers(len(earlier)))]
        shift = at - rot @ anchor
        placed.append((verts @ rot.T + shift, faces, inside, rot, shift))
    kept = []
    for j, (verts, faces, *_) in enumerate(placed):
        centroid = verts[faces].mean(axis=1)
        hidden = np.zeros(len(faces), bool)
        for k, (_, _, inside, rot, shift) in enumerate(placed):
            if k != j:
                hidden |= inside((centroid - shift) @ rot)
        kept.append((verts, faces[~hidden]))
    verts, faces = _merge(*kept)
    return _finish(_deform(verts, rng, 0.6), faces)


def _extrusion_shape(rng: np.random.Generator) -> Mesh:
    """A star-shaped outline (a random smooth radius per angle, maybe with a notch) extruded
    along z and capped; being star-shaped around the origin it cannot self-intersect, and
    its caps are grids of rays from the origin."""
    k = np.arange(1, 7)
    coef = rng.normal(0.0, 0.2, (2, len(k))) / k  # smooth: higher harmonics weaker
    notch = rng.random() < 0.6
    at, width, depth = rng.uniform(0, 2 * np.pi), rng.uniform(0.15, 0.35), rng.uniform(0.25, 0.5)
    aspect, height = rng.uniform(0.55, 1.0), rng.uniform(0.8, 2.0)

    def outline(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        kt = t[..., None] * k
        r = 1 + np.cos(kt) @ coef[0] + np.sin(kt) @ coef[1]
        if notch:
            gap = np.angle(np.exp(1j * (t - at)))
            r = r * (1 - depth * np.exp(-(gap**2) / (2 * width**2)))
        r = np.maximum(r, 0.3)
        return r * np.cos(t), aspect * r * np.sin(t)

    def side(t: np.ndarray, s: np.ndarray) -> np.ndarray:
        return np.stack([*outline(t), height * s], -1)

    def cap(z: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        return lambda t, s: np.stack([*(s * c for c in outline(t)), np.full_like(t, z)], -1)

    t, s = _ring(96), np.linspace(0.0, 1.0, 5)
    mesh = _merge(
        _grid(side, t, np.linspace(0.0, 1.0, 8), True, False),
        _grid(cap(0.0), t, s, True, False),
        _grid(cap(height), t, s, True, False),
    )
    return _finish(_deform(mesh[0], rng, 0.7), mesh[1])


_FAMILY_BUILDERS: dict[str, Callable[[np.random.Generator], Mesh]] = {
    "superquadric": _superquadric_shape,
    "blend": _blend_shape,
    "extrusion": _extrusion_shape,
}


def _parse_family(name: str) -> tuple[str, int]:
    """``(family, seed)`` of a family name; ValueError saying what is wrong otherwise."""
    family, _, seed = str(name).partition("-")
    if family not in _FAMILY_BUILDERS:
        reason = "it is neither a fixed shape nor of a known family"
    elif not _SEED.fullmatch(seed):
        reason = f"the seed {seed!r} is not a non-negative integer without leading zeros"
    else:
        return family, int(seed)
    raise ValueError(
        f"unknown procedural shape {name!r}: {reason}; use one of "
        f"{', '.join(PROCEDURAL_SHAPES)}, or '<family>-<seed>' with <family> one of "
        f"{', '.join(PROCEDURAL_FAMILIES)} and <seed> a non-negative integer "
        "(e.g. 'superquadric-17')"
    )


_BUILDERS: dict[str, Callable[[], Mesh]] = {
    "torus": _torus,
    "box": _box,
    "cylinder": _cylinder,
    "cone": _cone,
    "capsule": _capsule,
    "helix-tube": _helix_tube,
}

#: Names of the shapes :func:`procedural_mesh` builds.
PROCEDURAL_SHAPES: tuple[str, ...] = tuple(_BUILDERS)


def procedural_mesh(name: str) -> Mesh:
    """Build one of the procedural meshes.

    A family name gives the same mesh on every call (its numbers are drawn from the seed
    alone; platforms whose numpy rounds sines or powers differently may differ in the last
    bits). Family meshes have a few thousand triangles (at most about 4,400), are centred
    with their largest norm 1, and take a few milliseconds to build.

    Parameters
    ----------
    name : str
        One of :data:`PROCEDURAL_SHAPES`, or ``"<family>-<seed>"`` with the family one of
        :data:`PROCEDURAL_FAMILIES` and the seed a non-negative integer written without
        leading zeros (``"superquadric-17"``, ``"blend-0"``, ``"extrusion-250"``).

    Returns
    -------
    vertices : numpy.ndarray
        (V, 3) float64.
    faces : numpy.ndarray
        (F, 3) int32 triangle indices.

    Raises
    ------
    ValueError
        If ``name`` is not a procedural shape (the message says what a valid name is).
    """
    if name in _BUILDERS:
        return _BUILDERS[name]()
    family, seed = _parse_family(name)
    return _FAMILY_BUILDERS[family](_family_rng(family, seed))


def is_procedural(name: object) -> bool:
    """Whether :func:`procedural_mesh` builds ``name``.

    Parameters
    ----------
    name : object
        A model name (anything else is not procedural).

    Returns
    -------
    bool
        True for the names of :data:`PROCEDURAL_SHAPES` and well-formed family names such as
        ``"blend-42"``; False for anything else, malformed family names included.
    """
    if not isinstance(name, str):
        return False
    if name in _BUILDERS:
        return True
    try:
        _parse_family(name)
    except ValueError:
        return False
    return True


def procedural_family_names(n: int, seed: int = 0) -> tuple[str, ...]:
    """Names of ``n`` distinct random shapes, for training on many shapes.

    The families take turns (:data:`PROCEDURAL_FAMILIES` order); each name's seed is drawn
    from ``seed``, one after another, so the first ``m`` names of a longer list are the
    ``m`` names of a shorter one.

    Parameters
    ----------
    n : int
        Number of names (>= 0).
    seed : int, default 0
        Seed of the draws (>= 0): two seeds give unrelated lists (that may share names).

    Returns
    -------
    tuple of str
        ``n`` distinct names such as ``"superquadric-305871"``.

    Raises
    ------
    ValueError
        If ``n`` or ``seed`` is negative or not an int, or ``n`` is over 3,000,000 (the
        names' seeds are below 1,000,000, for short names).
    """
    for label, value in (("n", n), ("seed", seed)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
            raise ValueError(f"{label} must be a non-negative int, got {value!r}")
    if n > len(PROCEDURAL_FAMILIES) * _NAME_SEEDS:
        raise ValueError(f"n must be at most {len(PROCEDURAL_FAMILIES) * _NAME_SEEDS:,}, got {n}")
    rng = np.random.default_rng(np.random.SeedSequence([_SALT, 0, int(seed)]))
    names: list[str] = []
    seen: set[str] = set()
    while len(names) < n:
        name = f"{PROCEDURAL_FAMILIES[len(names) % len(PROCEDURAL_FAMILIES)]}-"
        name += str(int(rng.integers(_NAME_SEEDS)))
        if name not in seen:
            seen.add(name)
            names.append(name)
    return tuple(names)
