"""The learned embedding: one place that resolves a network, knows its thresholds and units.

Every path that computes the embedding (`pointclm.register`, `register_batch`,
`register_point_clouds`, `evaluate`) goes through :func:`resolve`, which turns what the
caller gave into an :class:`Embedding`:

- a shipped name ("default", "paper") or a weight file (``.safetensors`` with its ``.json``):
  loaded once (cached) for the Rust forward pass, or for torch with ``backend="torch"``;
- a loaded :class:`pointclm.Network`: the Rust forward pass;
- a torch module (``torch.nn.Module``, e.g. a :class:`pointclm.model.SCNonlocal` being
  trained): torch.

An :class:`Embedding` knows the network's training units (its ``sigma_d``: the network was
trained on correspondences whose spatial-consistency tolerance was that length) and converts
coordinates to them (:func:`network_units`), and it reads the thresholds recommended with the
network from its weight file's metadata.

Networks are recognised by type (``isinstance``), never by class name. torch is imported
only when a torch network is asked for, so the Rust path runs on a torch-free install.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from . import _core
from .config import Config
from .cues import needed, pack
from .errors import ConfigError, InputError
from .model.weights import SHIPPED, load_metadata, load_network, weights_path

__all__ = [
    "BACKENDS",
    "Embedding",
    "check_backend",
    "is_network",
    "is_torch_module",
    "is_weights",
    "network_units",
    "resolve",
]

#: Where the embedding is computed: the core's own forward pass, or torch.
BACKENDS = ("rust", "torch")

#: The metadata key of each kind of recommended thresholds (see `Embedding.recommended_config`).
RecommendedFor = Literal["correspondences", "point_clouds", "point_clouds_no_refine"]
_METADATA_KEYS = {
    "correspondences": "recommended_config",
    "point_clouds": "recommended_point_cloud_config",
    "point_clouds_no_refine": "recommended_point_cloud_config_no_refine",
}


def is_weights(model: Any) -> bool:
    """A shipped name or a path (either backend loads it), as opposed to a loaded network."""
    return isinstance(model, str | os.PathLike)


def is_network(model: Any) -> bool:
    """A network loaded for the Rust forward pass (:class:`pointclm.Network`)."""
    return isinstance(model, _core.Network)


def is_torch_module(model: Any) -> bool:
    """A torch module. Without torch imported nothing can be one, so this never imports it
    (the Rust path must work where torch is missing or blocked)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(model, torch.nn.Module)


def network_units(corr: np.ndarray, sigma_d: float, network_sigma_d: float) -> np.ndarray:
    """Correspondences in the units a network was trained in: each side centred on its
    centroid (translations change no consistency, and the network must not depend on where a
    scan's origin lies) and scaled by ``network_sigma_d / sigma_d``, so the network attends
    with the length tolerance it was trained with. `sigma_d` is the pipeline's tolerance in
    the units of `corr`. The input is not modified."""
    c = np.asarray(corr, dtype=np.float64)
    centred = np.hstack([c[:, :3] - c[:, :3].mean(0), c[:, 3:] - c[:, 3:].mean(0)])
    return np.ascontiguousarray(centred * (network_sigma_d / sigma_d))


def check_backend(backend: Any, model: Any, device: Any) -> str:
    """`backend` checked against `model` and `device` (nothing is loaded); returns it."""
    if backend not in BACKENDS:
        raise InputError(f"backend must be 'rust' or 'torch', got {backend!r}")
    if device is not None:
        if model is None:
            raise InputError("device= applies to the learned embedding: pass model= too")
        if backend != "torch" and device != "cpu":
            raise InputError(
                f"device={device!r} needs backend='torch'; the Rust network runs on the CPU"
            )
    if model is None:
        return str(backend)
    if isinstance(model, Embedding):
        if model.backend != backend:
            raise InputError(f"this Embedding runs on backend={model.backend!r}, not {backend!r}")
    elif is_network(model):
        if backend != "rust":
            raise InputError("a pointclm.Network is evaluated by backend='rust'")
    elif not is_weights(model) and backend != "torch":
        raise InputError(
            f"model of type {type(model).__name__} needs backend='torch'; the Rust backend "
            "takes a shipped name, a weight file or a pointclm.Network"
        )
    return str(backend)


@dataclass(frozen=True)
class Embedding:
    """A resolved network (see :func:`resolve`): what computes the embedding and where.

    ``network`` is a :class:`pointclm.Network` (``backend`` "rust") or a torch module
    (``backend`` "torch", run on ``device``); ``path`` is the weight file it came from (its
    metadata holds the recommended thresholds), None for a torch module built in memory.
    """

    network: Any
    backend: str
    path: Path | None = None
    device: str = "cpu"

    @property
    def sigma_d(self) -> float:
        """The network's training units: the spatial-consistency tolerance it was trained
        with. A torch module without an architecture config has the shipped networks' (the
        synthetic protocol's, `Config().sigma_d`)."""
        if self.backend == "rust":
            return float(self.network.sigma_d)
        arch = getattr(self.network, "config", None)
        return float(getattr(arch, "sigma_d", Config().sigma_d))

    @property
    def inputs(self) -> tuple[str, ...]:
        """What the network takes besides coordinates (:data:`pointclm.cues.INPUTS`)."""
        if self.backend == "rust":
            return tuple(getattr(self.network, "inputs", ()))
        arch = getattr(self.network, "config", None)
        return tuple(getattr(arch, "inputs", ()))

    def pipeline_normals(self, normals: Any) -> Any:
        """The `normals` the pipeline's beta gets with this network: those of a network that
        takes them (as `register_point_clouds` gives them), else None."""
        return normals if "normals" in self.inputs else None

    def in_training_units(self, sigma_d: float) -> bool:
        """Whether coordinates whose pipeline tolerance is `sigma_d` are already in the
        network's units (then they go to it as they are)."""
        return bool(sigma_d == self.sigma_d)

    def embed(
        self,
        corr: np.ndarray,
        sigma_d: float | None = None,
        *,
        num_threads: int | None = None,
        normals: Any = None,
        similarity: Any = None,
    ) -> np.ndarray:
        """(N, 6) correspondences -> (N, C) unit embeddings (float64).

        With `sigma_d` (the pipeline's tolerance in the units of `corr`) the network sees
        them in its training units (:func:`network_units`); None: as they are. `normals`
        ((N, 6)) and `similarity` ((N,)) are the cues of :mod:`pointclm.cues`, needed when
        the network takes them (:attr:`inputs`) and ignored otherwise.
        """
        x = corr if sigma_d is None else network_units(corr, sigma_d, self.sigma_d)
        inputs = self.inputs
        if self.backend == "rust":
            cues = needed(inputs, len(x), normals, similarity)
            return np.asarray(self.network.embed(x, num_threads=num_threads, **cues))
        from .model.embed import embed  # torch is imported only when asked for

        return embed(pack(x, inputs, normals, similarity), self.network, device=self.device)

    def recommended_config(self, purpose: RecommendedFor = "correspondences") -> Config | None:
        """The thresholds chosen with this network (in the synthetic protocol's units), or
        None when it carries none (a torch module built in memory: the defaults apply).

        `purpose`: "correspondences" (`register`), "point_clouds" (`register_point_clouds`
        with refinement, before scaling to the voxel), "point_clouds_no_refine" (without);
        the point-cloud ones fall back to the correspondence ones.
        """
        if purpose not in _METADATA_KEYS:
            raise InputError(f"purpose must be one of {sorted(_METADATA_KEYS)}, got {purpose!r}")
        if purpose == "correspondences" and self.backend == "rust":
            # The core reads the metadata with the weights: ask it rather than read twice.
            return Config(**self.network.recommended_config())
        if self.path is None:
            return None
        meta = load_metadata(self.path)
        key = _METADATA_KEYS[purpose]
        return _config_from(meta.get(key, meta.get(_METADATA_KEYS["correspondences"], {})))


def _config_from(values: Any) -> Config:
    """A metadata entry as a Config, naming unknown keys as `pointclm.register` does."""
    if not isinstance(values, dict):
        raise ConfigError(f"recommended thresholds must be a JSON object, got {values!r}")
    return Config.from_dict(values)


def resolve(model: Any, backend: str | None = None, device: str | None = None) -> Embedding:
    """What `model` names, loaded: an :class:`Embedding`.

    `model`: a shipped name ("default", "paper"), a weight file, a :class:`pointclm.Network`,
    a torch module, or an :class:`Embedding` (returned as it is). `backend`: "rust", "torch",
    or None to choose by `model` (a torch module runs on torch, the rest on the Rust core).
    `device`: the torch device (default "cpu"). Weight files are loaded once and cached.
    """
    if backend is None:
        backend = _natural_backend(model)
    backend = check_backend(backend, model, device)
    if isinstance(model, Embedding):
        return model
    if backend == "rust":
        network = model if is_network(model) else load_network(model)
        return Embedding(network, "rust", Path(network.path))
    device = device or "cpu"
    if not is_weights(model):
        return Embedding(model, "torch", None, device)
    from .model.embed import resolve_model  # torch is imported only when asked for

    return Embedding(resolve_model(model, device), "torch", weights_path(model), device)


def _natural_backend(model: Any) -> str:
    if isinstance(model, Embedding):
        return model.backend
    if is_torch_module(model):
        return "torch"
    if is_weights(model) or is_network(model):
        return "rust"
    raise InputError(
        f"model must be a shipped name ({', '.join(SHIPPED)}), a weight file, a "
        f"pointclm.Network or a torch module, got {type(model).__name__}"
    )
