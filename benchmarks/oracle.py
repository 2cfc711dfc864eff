"""Oracle timing: 1000 DC motor initial states (bar: under a minute on 2 cores), 200 bicycle and
200 attitude states; prints the time and the ceiling per tolerance of each task. With both tasks
(the default) it then makes their minima consistent (``tighten``: a state's ``reach`` minimum is at
most its ``reach_avoid`` minimum, every adopted sequence verified by replay) and prints the
tightened ceilings, and the search's prefix check against the numpy replay (a ratio, in the run).

    /work/venv/bin/python benchmarks/oracle.py [--workers 2] [--dc 1000] [--bicycle 200] [--attitude 200]
        [--task both|reach|reach_avoid] [--restarts K] [--no-interval-bound]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import asap_dsl
from asap_dsl.backends.oracle.search import Oracle
from asap_dsl.backends.oracle.solver import run, tighten

SPECS = Path(__file__).resolve().parents[1] / "specs"


def _ceil(rep) -> str:
    return ", ".join(f"{row['tolerance']}: {100 * row['rate']:.1f}% "
                     f"[{100 * row['ci95'][0]:.1f}, {100 * row['ci95'][1]:.1f}]" for row in
                     (rep.ceiling(t) for t in sorted(rep.tolerances)))


def _prefix_check_ratio(prog, rep) -> None:
    """The search checks every IPOPT solution's prefixes: time that check on the report's action
    sequences as the search does it (CasADi rollout, one pass) against the simulator's numpy
    replay checked the same way, in this run; both must give the same prefixes."""
    oracle = Oracle(prog, rep.task, restarts=0)  # no NLP is built
    cases = [(r.x0, r.actions) for r in rep.results if r.actions is not None and len(r.actions)]
    if not cases:
        return
    t0 = time.perf_counter()
    fast = [oracle.passing_prefix(oracle._rollout(x0, U)) for x0, U in cases]
    t_fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    slow = [oracle.first_passing_prefix(x0, U) for x0, U in cases]
    t_slow = time.perf_counter() - t0
    print(f"  prefix check, {len(cases)} sequences: rollout {1000 * t_fast / len(cases):.2f} ms, numpy replay "
          f"{1000 * t_slow / len(cases):.2f} ms a sequence: {t_slow / t_fast:.1f}x; "
          f"{'the same prefixes' if fast == slow else 'PREFIXES DIFFER'}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dc", type=int, default=1000)
    ap.add_argument("--bicycle", type=int, default=200)
    ap.add_argument("--attitude", type=int, default=200)
    ap.add_argument("--task", default="both", help="reach, reach_avoid or both (default; then tightened)")
    ap.add_argument("--restarts", type=int, default=None, help="extra initial guesses (default: the oracle's)")
    ap.add_argument("--no-interval-bound", action="store_true", help="start the non-linear N-search at 1")
    args = ap.parse_args()
    tasks = ["reach", "reach_avoid"] if args.task == "both" else [args.task]
    print(f"oracle benchmark: {os.cpu_count()} CPUs, workers={args.workers}, tasks {', '.join(tasks)}, seed 2024, "
          f"restarts {'default' if args.restarts is None else args.restarts}, "
          f"interval bound {'off' if args.no_interval_bound else 'on'}")
    print(f"{'spec':<10} {'task':<12} {'label':<6} {'states':>6} {'time s':>8} {'ms/state':>9} {'solves':>7} "
          f"{'restart':>7} {'fail':>5} {'unver':>5}  ceiling per tolerance")
    ok = True
    for name, n in (("dc_motor", args.dc), ("bicycle", args.bicycle), ("attitude", args.attitude)):
        if n <= 0:
            continue
        prog = asap_dsl.load(SPECS / f"{name}.asap")
        reports = []
        for task in tasks:
            t0 = time.perf_counter()
            rep = run(prog, task, episodes=n, workers=args.workers, restarts=args.restarts,
                      interval_bound=not args.no_interval_bound)
            dt = time.perf_counter() - t0
            reports.append(rep)
            c = rep.counts()
            solves = sum(r.solves for r in rep.results)
            restarts = sum(r.restarts for r in rep.results)
            print(f"{name:<10} {task:<12} {rep.label:<6} {n:>6} {dt:>8.1f} {1000 * dt / n:>9.1f} {solves:>7} "
                  f"{restarts:>7} {c['solver_failures']:>5} {c['unverified']:>5}  {_ceil(rep)}", flush=True)
            if name == "dc_motor" and task == "reach":
                ok = dt < 60.0
                print(f"  bar: 1000 DC motor states under 60 s -> {'met' if ok else 'MISSED'} ({dt:.1f} s)")
        _prefix_check_ratio(prog, reports[-1])
        if len(reports) > 1:
            t0 = time.perf_counter()
            improved = tighten(prog, reports)
            dt = time.perf_counter() - t0
            for rep in reports:
                c = rep.counts()
                print(f"{name:<10} {rep.task:<12} tightened ({improved[rep.task]} states improved, {dt:.2f} s), "
                      f"unver {c['unverified']}:  {_ceil(rep)}", flush=True)
            r, ra = (reports[0].steps, reports[1].steps)
            bad = int(sum(1 for a, b in zip(r, ra) if a > b))
            print(f"  consistency: states with reach minimum > reach_avoid minimum: {bad}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
