"""Weight files: a safetensors file of the state dict beside a JSON of the architecture.

safetensors is a plain, documented format (8-byte header length, JSON header, raw tensors)
that the Rust core can read too, and loading it never executes code (unlike pickle).
"""

from __future__ import annotations

import json
import os
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .. import _core
from ..errors import InputError, WeightsError, WeightsNotFoundError
from ..io.files import read_checked

if TYPE_CHECKING:
    from .network import SCNonlocal

__all__ = [
    "DEFAULT_WEIGHTS",
    "SHIPPED",
    "load_metadata",
    "load_model",
    "load_network",
    "require_device",
    "require_torch",
    "save_model",
    "weights_path",
]

WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
# Shipped networks by name: "default" is the compact one (fast on a CPU), "paper" the
# paper-size one (12 x 128). See MODEL_CARD.md.
SHIPPED = {
    "default": WEIGHTS_DIR / "default.safetensors",
    "paper": WEIGHTS_DIR / "paper.safetensors",
}
DEFAULT_WEIGHTS = SHIPPED["default"]


def weights_path(model: str | os.PathLike[str]) -> Path:
    """A shipped name ("default", "paper") or a path -> the .safetensors path."""
    if isinstance(model, str) and model in SHIPPED:
        return SHIPPED[model]
    if not isinstance(model, str | os.PathLike) or isinstance(os.fspath(model), bytes):
        raise InputError(
            f"model must be a shipped name ({', '.join(SHIPPED)}) or a path to a "
            f".safetensors file, got {type(model).__name__}"
        )
    if os.fspath(model) == "" or "\x00" in os.fspath(model):
        raise InputError(f"model {os.fspath(model)!r} is not a valid path")
    return Path(model)


def _shipped_hint() -> str:
    names = ", ".join(repr(n) for n in SHIPPED)
    return (
        f"the shipped networks are {names} (e.g. model='default', --model default); any "
        "other model is the path of a .safetensors file with its .json beside it"
    )


def _check_exists(path: Path) -> None:
    """A WeightsNotFoundError naming `path` and the shipped names when there is no weight
    file at `path` (a mistyped name lands here: it is read as a relative path)."""
    if not path.is_file():
        what = "not a file" if path.exists() else "no such file"
        raise WeightsNotFoundError(f"no weights at {path}: {what}; {_shipped_hint()}")


def load_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The JSON beside a weight file (architecture, training config, metrics).

    Raises WeightsNotFoundError (a FileNotFoundError) when it is missing, WeightsError when
    it cannot be read or is not a JSON object.
    """
    cfg = weights_path(path).with_suffix(".json")
    try:
        _, raw = read_checked(cfg, "weight metadata file")
        meta = json.loads(raw)
    except FileNotFoundError as e:
        raise WeightsNotFoundError(f"unreadable weight metadata {cfg}: {e}") from None
    except (OSError, ValueError) as e:  # JSONDecodeError and UnicodeDecodeError included
        raise WeightsError(f"unreadable weight metadata {cfg}: {e}") from None
    if not isinstance(meta, dict):
        raise WeightsError(f"unreadable weight metadata {cfg}: expected a JSON object")
    return meta


def require_torch() -> Any:
    """The torch module, or an ImportError that says how to install it."""
    try:
        import torch
    except ImportError:
        raise ImportError(
            "the learned embedding needs torch: pip install 'pointclm[train]' "
            "(or use model=None for the training-free pipeline)"
        ) from None
    return torch


def require_device(device: str) -> None:
    """Check that torch can run on `device`: an InputError saying what to do when it names
    CUDA and torch has none (a CPU build, or no GPU visible), or is not a device at all."""
    torch = require_torch()
    try:
        kind = torch.device(device).type
    except (RuntimeError, ValueError, TypeError):
        raise InputError(
            f"device={device!r} is not a torch device (e.g. 'cpu', 'cuda', 'cuda:1')"
        ) from None
    if kind == "cuda" and not torch.cuda.is_available():
        why = (
            f"this torch ({torch.__version__}) is built without CUDA"
            if torch.version.cuda is None
            else "torch sees no CUDA GPU on this machine"
        )
        raise InputError(
            f"device={device!r}: CUDA is not available ({why}). Use device='cpu', or "
            "backend='rust' (the default), which runs the network on the CPU without torch; "
            "for a GPU, install a CUDA build of torch (https://pytorch.org) on a machine with "
            "an NVIDIA driver"
        )


def _config_path(path: Path) -> Path:
    return path.with_suffix(".json")


def load_network(path: str | os.PathLike[str] | None = None) -> _core.Network:
    """The network stored at `path` or shipped under that name (default: "default") for the
    Rust forward pass (no torch needed), loaded once per file version and cached.

    Raises WeightsNotFoundError (a FileNotFoundError) when a file is missing, WeightsError
    when it does not match its architecture (both are ValueErrors).
    """
    p = weights_path(path) if path is not None else DEFAULT_WEIGHTS
    p = Path(os.path.abspath(p))
    _check_exists(p)
    stamps: list[tuple[int, int] | None] = []
    for f in (p, _config_path(p)):
        try:
            st = f.stat()
            stamps.append((st.st_mtime_ns, st.st_size))
        except OSError:
            stamps.append(None)  # the core names the missing file
    return _cached_network(str(p), tuple(stamps))


@lru_cache(maxsize=8)
def _cached_network(path: str, _stamps: tuple[Any, ...]) -> _core.Network:
    return _core.Network(path)


def save_model(model: SCNonlocal, path: str | Path, extra: dict[str, Any] | None = None) -> Path:
    """Write `path` (.safetensors) and `path` with .json (architecture + `extra` metadata).

    The architecture holds `depth`, `width`, `sigma_d`, for a network with inputs beyond the
    coordinates `inputs` and `normal_tolerance`, and for one with per-scene normalization
    `normalization` (`EmbeddingConfig.as_dict`)."""
    from safetensors.torch import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    save_file(state, str(path))
    meta = {"architecture": model.config.as_dict(), **(extra or {})}
    _config_path(path).write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    return path


def load_model(path: str | Path | None = None, device: str = "cpu") -> SCNonlocal:
    """The network stored at `path` or shipped under that name (default: "default"), in eval
    mode.

    Raises WeightsNotFoundError (a FileNotFoundError) when a file is missing, WeightsError
    when it does not match its architecture (both are ValueErrors).
    """
    require_torch()
    from safetensors.torch import load_file

    from .network import EmbeddingConfig, SCNonlocal

    require_device(device)
    path = weights_path(path) if path is not None else DEFAULT_WEIGHTS
    _check_exists(Path(os.path.abspath(path)))
    cfg_path = _config_path(path)
    if not path.is_file() or not cfg_path.is_file():
        raise WeightsNotFoundError(f"no weights at {path} (needs {path.name} and {cfg_path.name})")
    try:
        arch = json.loads(cfg_path.read_text())["architecture"]
        model = SCNonlocal(EmbeddingConfig(**arch))
        state = load_file(str(path), device=device)
    except (KeyError, TypeError, json.JSONDecodeError, OSError) as e:
        raise WeightsError(f"unreadable weights {path}: {e}") from None
    except Exception as e:  # safetensors raises its own error type on corrupt files
        raise WeightsError(f"unreadable weights {path}: {e}") from None
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise WeightsError(f"weights {path} do not match architecture {arch}: {e}") from None
    model.to(device).eval()
    return model
