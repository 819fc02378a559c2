"""pointclm: multi-instance point cloud registration (PointCLM, ECCV 2022) on a Rust core.

>>> import pointclm
>>> from pointclm.datasets import make_scene
>>> scene = make_scene(seed=0)
>>> result = pointclm.register(scene.correspondences)
>>> result.transformations.shape[1:]
(4, 4)
"""

from typing import TYPE_CHECKING, Any

from . import errors
from ._core import Instance, Network, RegistrationResult, __version__
from .clouds.joint import register_models
from .config import Config
from .point_clouds import CloudInstance, register_point_clouds
from .refinement import RefinementContext, refine_poses
from .registration import register, register_batch
from .scene_rules import SceneRules

if TYPE_CHECKING:
    from . import io
    from .batch import register_files

__all__ = [
    "CloudInstance",
    "Config",
    "Instance",
    "Network",
    "RefinementContext",
    "RegistrationResult",
    "SceneRules",
    "__version__",
    "errors",
    "io",
    "refine_poses",
    "register",
    "register_batch",
    "register_files",
    "register_models",
    "register_point_clouds",
]


def __getattr__(name: str) -> Any:
    # `pointclm.io` loads on first use (PEP 562): reachable after `import pointclm` alone,
    # without its readers' 30 ms in every `import pointclm` (measured: 176 -> 207 ms eager).
    # `register_files` too: it needs `pointclm.io` to list and read the scans.
    if name in ("io", "register_files"):
        import importlib

        if name == "io":
            return importlib.import_module(f"{__name__}.io")
        return importlib.import_module(f"{__name__}.batch").register_files
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), "io", "register_files"})
