"""`pointclm register --bop-csv` and `pointclm batch --bop-csv`: the poses found in the BOP
challenge's CSV."""

from __future__ import annotations

import argparse
from typing import Any

from .args import _finite_float, _int_at_least


def _add_bop_flags(p: argparse.ArgumentParser, batch: bool = False) -> None:
    p.add_argument(
        "--bop-csv",
        metavar="FILE",
        help="also write the poses in the BOP challenge's CSV (scene_id,im_id,obj_id,score,"
        "R,t,time; score: confidence, t in mm, time: the registration's seconds)"
        + ("; one file for the batch, written once it is through, a scan per image" * batch),
    )
    p.add_argument("--scene-id", type=_int_at_least(0), default=0, help="BOP scene id (default 0)")
    if batch:
        p.add_argument(
            "--im-id-from",
            choices=["index", "stem"],
            default="index",
            help="a scan's BOP image id: its position in SCANS as expanded (index, default: "
            "0, 1, ...) or the number its file is named by (stem: 000042.ply is image 42)",
        )
    else:
        p.add_argument("--im-id", type=_int_at_least(0), default=0, help="BOP image id (default 0)")
    p.add_argument(
        "--obj-id",
        type=_int_at_least(0),
        action="append",
        help="BOP object id (default 1); with several models, once per model in order",
    )
    p.add_argument(
        "--unit-to-mm",
        type=_finite_float,
        default=1000.0,
        metavar="MM",
        help="millimetres in one unit of the files, for --bop-csv (default 1000: metres; 1 "
        "for files in millimetres such as BOP's own models)",
    )


def _check_bop_args(args: argparse.Namespace, models: int = 1) -> None:
    """The BOP flags checked before the work; ``args.obj_ids``: one object id per model."""
    from ..errors import InputError
    from ..io.files import check_output_path

    ids = args.obj_id or [1]
    if len(ids) != models and (args.bop_csv or args.obj_id):
        raise InputError(
            f"{len(args.obj_id or [])} --obj-id for {models} model(s): with several models "
            "--bop-csv needs one object id per model, in the models' order"
            if models > 1
            else f"{len(ids)} --obj-id for one model: give one"
        )
    args.obj_ids = ids
    if args.bop_csv:
        check_output_path(args.bop_csv, "--bop-csv")
        if args.unit_to_mm <= 0:
            raise ValueError(f"--unit-to-mm must be positive, got {args.unit_to_mm:g}")


def _write_bop(args: argparse.Namespace, reg: Any) -> None:
    """`reg`'s poses (a list: one result per model, `args.obj_ids` in order) as BOP's CSV."""
    from ..io.bop import write_bop_csv

    if args.bop_csv:
        regs = reg if isinstance(reg, list) else [reg]
        write_bop_csv(
            regs, args.bop_csv, args.scene_id, args.im_id, args.obj_ids, unit_to_mm=args.unit_to_mm
        )


def _write_batch_bop(args: argparse.Namespace) -> int:
    """The batch's BOP CSV from its output; returns the poses written (0 without --bop-csv)."""
    from ..batch import expand_scans
    from ..batch.bop import write_batch_bop_csv

    if not args.bop_csv:
        return 0
    return write_batch_bop_csv(
        args.out,
        expand_scans(args.scans),
        args.bop_csv,
        scene_id=args.scene_id,
        obj_id=args.obj_ids,
        im_id_from=args.im_id_from,
        unit_to_mm=args.unit_to_mm,
    )
