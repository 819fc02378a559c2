"""One scale measurement in a fresh process:
``python -m benchmarks.correspondences.scale_child N [SEED]``.

Builds ``make_planted_scene(N, SEED)``, reads the peak RSS (baseline: interpreter, numpy,
pointclm and the scene), runs ``pointclm.register`` once with the default config and threads,
reads the peak RSS again and prints one JSON line. `protocol` starts it through
``sh`` so that its ``ru_maxrss`` does not start from the parent's RSS (on Linux a forked child
inherits the parent's peak, and exec keeps it).
"""

from __future__ import annotations

import json
import resource
import sys
import time


def _mb() -> dict[str, float]:
    """Peak RSS of this process in MB: ru_maxrss, and /proc's VmHWM as a cross-check."""
    out = {"ru_maxrss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                out["vmhwm"] = int(line.split()[1]) / 1024
    return out


def main() -> None:
    n = int(sys.argv[1])
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0

    import pointclm
    from pointclm.datasets import make_planted_scene
    from pointclm.metrics import score_scene

    scene = make_planted_scene(n, seed=seed)
    baseline = _mb()
    t = time.perf_counter()
    r = pointclm.register(scene.correspondences, seed=0)
    seconds = time.perf_counter() - t
    peak = _mb()
    score = score_scene(r.transformations, scene.poses)
    print(
        json.dumps(
            {
                "n": n,
                "seconds": seconds,
                "timings": dict(r.timings),
                "kept": len(r.kept),
                "found": len(r.transformations),
                "gt": len(scene.poses),
                "matched": score.n_matched,
                "strict_f1": score.strict_f1,
                "baseline_mb": baseline,
                "peak_mb": peak,
            }
        )
    )


if __name__ == "__main__":
    main()
