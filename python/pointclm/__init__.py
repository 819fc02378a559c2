"""pointclm: multi-instance point cloud registration (PointCLM, ECCV 2022) on a Rust core.

>>> import pointclm
>>> from pointclm.datasets import make_scene
>>> scene = make_scene(seed=0)
>>> result = pointclm.register(scene.correspondences)
>>> result.transformations.shape[1:]
(4, 4)
"""

from ._core import Instance, Network, RegistrationResult, __version__
from .config import Config
from .point_clouds import CloudInstance, register_point_clouds
from .refinement import refine_poses
from .registration import register, register_batch

__all__ = [
    "CloudInstance",
    "Config",
    "Instance",
    "Network",
    "RegistrationResult",
    "__version__",
    "refine_poses",
    "register",
    "register_batch",
    "register_point_clouds",
]
