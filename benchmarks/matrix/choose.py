"""Choosing a rule on the validation matrix: several full runs, one per value of the rule,
compared cell by cell on the validation half.

    python -m benchmarks.matrix.choose LABEL=RUN.json LABEL=RUN.json ... [--row default]
                                       [--tolerance 0.03] [--out FILE]

Each ``RUN.json`` is the ``--out`` of ``python -m benchmarks.matrix.run`` with one value of
the rule (``--scene RULE=VALUE``, ``--descriptor``, ...). Per cell, the F1 of ``--row`` on the
validation seeds under each value, the best of them, and each value's loss against that best;
a value is admissible when it loses at most ``--tolerance`` on every cell (the matrix's rule for
defaults). The test half is reported beside it and never chosen on. Cells the runs do not share
are left out; the correspondence family has its own row and is compared on it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from benchmarks.common.report import write_report


def _f1(cell: dict, row: str, half: str) -> float | None:
    """The F1 of `row` (or of the correspondence row, for that family) on `half`."""
    rows = cell["rows"]
    got = rows.get(row) or rows.get("correspondences")
    if got is None:
        return None
    value = got[half]["f1"]
    return None if value is None else float(value)


def compare(runs: dict[str, dict], row: str = "default", tolerance: float = 0.03) -> dict:
    """Per shared cell, each label's validation and test F1 and its validation loss against
    the best label; per label, the worst loss, the cells it loses more than `tolerance` on,
    and the pooled F1 of `row` (validation, test)."""
    labels = list(runs)
    shared = [c for c in runs[labels[0]]["cells"] if all(c in r["cells"] for r in runs.values())]
    cells: dict[str, dict] = {}
    for name in shared:
        val = {lb: _f1(runs[lb]["cells"][name], row, "validation") for lb in labels}
        test = {lb: _f1(runs[lb]["cells"][name], row, "test") for lb in labels}
        known = [v for v in val.values() if v is not None]
        if not known:
            continue
        best = max(known)
        loss = {lb: None if v is None else best - v for lb, v in val.items()}
        cells[name] = {"validation": val, "test": test, "loss": loss}
    summary = {}
    for lb in labels:
        losses = {n: c["loss"][lb] for n, c in cells.items() if c["loss"][lb] is not None}
        pooled = runs[lb].get("pooled", {}).get(row, {})
        summary[lb] = {
            "worst_loss": max(losses.values(), default=0.0),
            "over": sorted(n for n, v in losses.items() if v > tolerance + 1e-9),
            "pooled": tuple(pooled.get(h, {}).get("f1") for h in ("validation", "test")),
        }
    return {"cells": cells, "labels": summary, "row": row, "tolerance": tolerance}


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def report(result: dict) -> str:
    """The comparison as markdown: one line per cell where the labels differ, then per label
    its worst loss, the cells over the tolerance and the pooled F1."""
    labels = list(result["labels"])
    head = " | ".join(f"{lb} val / test" for lb in labels)
    lines = [f"| cell | {head} | best (validation) |", "|---" * (len(labels) + 2) + "|"]
    for name, c in result["cells"].items():
        if (
            len({_fmt(v) for v in c["validation"].values()}) == 1
            and len({_fmt(v) for v in c["test"].values()}) == 1
        ):
            continue
        vals = " | ".join(f"{_fmt(c['validation'][lb])} / {_fmt(c['test'][lb])}" for lb in labels)
        best = ", ".join(lb for lb in labels if c["loss"][lb] == 0)
        lines.append(f"| {name} | {vals} | {best} |")
    lines += [
        "",
        f"Row `{result['row']}`; cells not listed give the same F1 under every value. "
        f"Admissible: no cell loses more than {result['tolerance']} F1 on the validation half.",
        "",
        "| value | worst loss | cells over the tolerance | pooled F1 val / test |",
        "|---|---|---|---|",
    ]
    for lb, s in result["labels"].items():
        over = ", ".join(s["over"]) or "none (admissible)"
        v, t = s["pooled"]
        lines.append(f"| {lb} | {s['worst_loss']:.2f} | {over} | {_fmt(v)} / {_fmt(t)} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> str:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", metavar="LABEL=RUN.json")
    ap.add_argument("--row", default="default", help="default, heap, ... (the run's rows)")
    ap.add_argument("--tolerance", type=float, default=0.03)
    ap.add_argument("--out", help="also write the markdown here")
    args = ap.parse_args(argv)
    runs = {}
    for item in args.runs:
        label, sep, path = item.rpartition("=")
        if not sep:
            raise SystemExit(f"give each run as LABEL=RUN.json, got {item!r}")
        runs[label] = json.loads(Path(path).read_text())
    text = report(compare(runs, args.row, args.tolerance))
    write_report(args.out, text)
    return text


if __name__ == "__main__":
    main()
