"""`pointclm train-descriptor`: train the learned local descriptor (needs torch)."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import fields
from pathlib import Path
from typing import Any

from .args import _check_folder_creatable, _finite_float, _int_at_least


def cmd_train_descriptor(args: argparse.Namespace) -> int:
    try:
        from ..training.descriptor import DescriptorTrainConfig, train_descriptor
    except ImportError as e:  # pragma: no cover - torch missing
        print(f"pointclm train-descriptor needs torch: pip install 'pointclm[train]' ({e})",
              file=sys.stderr)  # fmt: skip
        return 2
    from .commands import _check_device

    _check_folder_creatable(args.out, "--out")
    names = {f.name for f in fields(DescriptorTrainConfig)}
    given = {k: v for k, v in vars(args).items() if k in names and v is not None}
    cfg = DescriptorTrainConfig(**given)
    device = _check_device(args.device)
    path = train_descriptor(cfg, args.out, device=device, resume=args.resume,
                            progress=not args.quiet)  # fmt: skip
    print(json.dumps({"descriptor": str(path), "config": str(Path(path).with_suffix(".json"))}))
    return 0


def _add_train_descriptor_parser(sub: Any) -> None:
    t = sub.add_parser(
        "train-descriptor",
        help="train the learned local descriptor on rendered scans of the validation models "
        "(needs torch)",
    )
    t.add_argument("--out", required=True, help="output folder (descriptor, checkpoint)")
    t.add_argument("--scenes", type=_int_at_least(1), help="training scenes (default 300)")
    t.add_argument("--epochs", type=_int_at_least(1), help="passes over them (default 8)")
    t.add_argument("--lr", type=_finite_float, help="Adam's learning rate (default 0.002)")
    t.add_argument("--seed", type=_int_at_least(0), help="scenes and initial weights (default 0)")
    t.add_argument(
        "--device", default="auto", help="auto (default: cuda when available), cpu or cuda"
    )
    t.add_argument("--resume", action="store_true", help="continue from OUT's checkpoint")
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(func=cmd_train_descriptor)
