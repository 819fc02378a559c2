"""Shapes and synthetic benchmarks for multi-instance registration.

Why a separate subpackage: the registration core needs only numpy arrays of correspondences;
everything that *makes* such arrays (shape sampling, the paper's seeded synthetic protocol,
scale-test scenes) lives here, importable with numpy alone. Mesh files are read through
:func:`pointclm.io.read_mesh` (OBJ and STL need trimesh, ``pip install pointclm[io]``);
ModelNet40's HDF5 release needs h5py; both are imported only when used.
"""

from __future__ import annotations

from .bins import BinParams, BinScene, make_bin_scene
from .procedural import (
    PROCEDURAL_FAMILIES,
    PROCEDURAL_SHAPES,
    is_procedural,
    procedural_family_names,
    procedural_mesh,
)
from .scene_sensing import bunny_scan_pose
from .sensed import SensedScene, SensedSceneParams, make_packed_boxes, make_sensed_scene
from .shapes import (
    MESH_SUFFIXES,
    available_shapes,
    load_mesh,
    load_shape,
    modelnet40_shapes,
    normalize_unit_sphere,
    sample_surface,
)
from .synthetic import (
    SyntheticScene,
    label_correspondences,
    make_planted_scene,
    make_scene,
    make_scenes,
)

__all__ = [
    "BinParams",
    "BinScene",
    "MESH_SUFFIXES",
    "PROCEDURAL_FAMILIES",
    "PROCEDURAL_SHAPES",
    "SensedScene",
    "SensedSceneParams",
    "SyntheticScene",
    "available_shapes",
    "bunny_scan_pose",
    "is_procedural",
    "label_correspondences",
    "load_mesh",
    "load_shape",
    "make_bin_scene",
    "make_packed_boxes",
    "make_planted_scene",
    "make_scene",
    "make_scenes",
    "make_sensed_scene",
    "modelnet40_shapes",
    "normalize_unit_sphere",
    "procedural_family_names",
    "procedural_mesh",
    "sample_surface",
]
