"""Seconds for two sweep workers side by side: each pinned to a core of its own (what ``asapc
compare`` does when there are as many cores as workers) against left to the kernel, and one
training alone, measured in one run.

Each training process keeps helper threads busy beside its own (XLA's thread pool, the compiled
step's): unpinned, two workers on two cores take each other's. The jobs are the default preset's
(its oracle demonstrations included: a first pass, not counted, fills their cache, so every
measured pass reads them back alike), trained through the sweep's own workers
(:func:`asap_dsl.backends.compare.sweep.execute`) into fresh run directories.

    python benchmarks/sweep_workers.py [--spec specs/dc_motor.asap] [--task reach] [--steps 100000]

Prints each pass's wall time and the ratio unpinned / pinned (over 1: pinning is faster), and
two pinned runs against two runs one after the other (2 x alone).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from asap_dsl.backends.compare import sweep  # noqa: E402


def _pass(jobs, workers: int, pinned: bool) -> float:
    """Wall seconds to train ``jobs`` on ``workers`` sweep workers into a fresh directory."""
    free_core = sweep._free_core
    if not pinned:
        sweep._free_core = lambda pool, workers: None
    try:
        with tempfile.TemporaryDirectory(prefix="sweep-workers-") as runs:
            t0 = time.perf_counter()
            results = sweep.execute(jobs, runs, workers=workers)
            seconds = time.perf_counter() - t0
    finally:
        sweep._free_core = free_core
    bad = [r for r in results if r["status"] != "finished"]
    if bad:
        raise SystemExit(f"sweep_workers: a run did not finish: {bad[0].get('error')}")
    return seconds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spec", default="specs/dc_motor.asap")
    ap.add_argument("--task", default="reach")
    ap.add_argument("--steps", type=int, default=100_000)
    args = ap.parse_args()
    if len(os.sched_getaffinity(0)) < 2:
        print("sweep_workers: needs 2 cores", file=sys.stderr)
        return 2
    spec = str(Path(args.spec).resolve())
    two = [sweep.Job(spec, args.task, "sac", "asap", seed, steps=args.steps) for seed in (5, 6)]
    print(f"{Path(spec).stem} {args.task}, {args.steps:,} steps per run, default preset")
    _pass(two, 2, True)  # fills the demonstrations' cache for both seeds: not counted
    alone = _pass(two[:1], 1, False)
    unpinned = _pass(two, 2, False)
    pinned = _pass(two, 2, True)
    print(f"one run alone            {alone:7.1f} s")
    print(f"two side by side, free   {unpinned:7.1f} s")
    print(f"two side by side, pinned {pinned:7.1f} s")
    print(f"unpinned / pinned: {unpinned / pinned:.2f}x; two one after the other / two pinned: "
          f"{2 * alone / pinned:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
