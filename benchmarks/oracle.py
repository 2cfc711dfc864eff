"""Oracle timing: 1000 DC motor initial states (bar: under a minute on 2 cores), 200 bicycle and
200 attitude states; prints the time and the ceiling per tolerance of each.

    /work/venv/bin/python benchmarks/oracle.py [--workers 2] [--dc 1000] [--bicycle 200] [--attitude 200]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import asap_dsl
from asap_dsl.backends.oracle import run

SPECS = Path(__file__).resolve().parents[1] / "specs"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dc", type=int, default=1000)
    ap.add_argument("--bicycle", type=int, default=200)
    ap.add_argument("--attitude", type=int, default=200)
    ap.add_argument("--task", default="reach")
    args = ap.parse_args()
    print(f"oracle benchmark: {os.cpu_count()} CPUs, workers={args.workers}, task {args.task}, seed 2024")
    print(f"{'spec':<10} {'label':<6} {'states':>6} {'time s':>8} {'ms/state':>9} {'solves':>7} "
          f"{'fail':>5} {'unver':>5}  ceiling per tolerance")
    ok = True
    for name, n in (("dc_motor", args.dc), ("bicycle", args.bicycle), ("attitude", args.attitude)):
        if n <= 0:
            continue
        prog = asap_dsl.load(SPECS / f"{name}.asap")
        t0 = time.perf_counter()
        rep = run(prog, args.task, episodes=n, workers=args.workers)
        dt = time.perf_counter() - t0
        c = rep.counts()
        solves = sum(r.solves for r in rep.results)
        ceil = ", ".join(f"{row['tolerance']}: {100 * row['rate']:.1f}% "
                         f"[{100 * row['ci95'][0]:.1f}, {100 * row['ci95'][1]:.1f}]" for row in
                         (rep.ceiling(t) for t in sorted(rep.tolerances)))
        print(f"{name:<10} {rep.label:<6} {n:>6} {dt:>8.1f} {1000 * dt / n:>9.1f} {solves:>7} "
              f"{c['solver_failures']:>5} {c['unverified']:>5}  {ceil}", flush=True)
        if name == "dc_motor":
            ok = dt < 60.0
            print(f"  bar: 1000 DC motor states under 60 s -> {'met' if ok else 'MISSED'} ({dt:.1f} s)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
