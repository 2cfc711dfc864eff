"""The planner against the oracle (issue 17's validation), and the planner on the swimmer.

``--validate``: DC motor and bicycle, ``reach``, the seeded states (default 200 each): the oracle's
ceiling and the planner's achievable rate per tolerance with their 95% Wilson intervals, the
difference in points, how many states the planner reaches in the oracle's minimum, later, or
sooner (the oracle's local minima are upper bounds too), and both times. The bar: the planner
within 3 points of the ceiling at every tolerance, never above it beyond the intervals.

``--swimmer``: both swimmer tasks on the seeded states (default 200), one after the other, then
made consistent (``tighten_planned``); the achievable rates, the steps' distribution and the time.

    .venv/bin/python benchmarks/planner.py --validate [--states 200] [--workers 2] [--samples N] [--iterations N]
    .venv/bin/python benchmarks/planner.py --swimmer [--states 200] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import asap_dsl
from asap_dsl.backends.oracle.planner import PlannerBudget
from asap_dsl.backends.oracle.planning import plan_states, shortest_sequences, tighten_planned
from asap_dsl.stl import ir
from asap_dsl.backends.oracle.solver import run

SPECS = Path(__file__).resolve().parents[1] / "specs"


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def _row(rep, T: int) -> str:
    c = rep.ceiling(T)
    return f"{_pct(c['rate'])}% [{_pct(c['ci95'][0])}, {_pct(c['ci95'][1])}]"


def validate(spec: str, task: str, states: int, workers: int, budget: PlannerBudget) -> dict:
    prog = asap_dsl.load(SPECS / spec)
    t0 = time.perf_counter()
    oracle = run(prog, task, episodes=states, workers=workers)
    t_oracle = time.perf_counter() - t0
    t0 = time.perf_counter()
    planned = plan_states(prog, task, episodes=states, workers=workers, budget=budget)
    t_plan = time.perf_counter() - t0
    a, b = planned.steps, oracle.steps
    both = np.isfinite(a) & np.isfinite(b)
    print(f"\n{spec} {task}: {states} states; oracle ({oracle.label}) {t_oracle:.1f} s, planner {t_plan:.1f} s "
          f"({planned.extra['planner']['rollouts']:,} rollouts)")
    print("| tolerance | oracle ceiling | planner (achievable) | difference | within the intervals |")
    print("|---|---|---|---|---|")
    ok = True
    for T in sorted(prog.task(task).model.tolerances):
        co, cp = oracle.ceiling(T), planned.ceiling(T)
        diff = 100 * (cp["rate"] - co["rate"])
        inside = cp["rate"] <= co["ci95"][1] + 1e-12
        ok &= abs(diff) <= 3.0 and inside
        print(f"| {T} | {_row(oracle, T)} | {_row(planned, T)} | {diff:+.1f} pts | {'yes' if inside else 'NO'} |")
    print(f"states both reach: {int(both.sum())}; in the oracle's minimum {int(np.sum(a[both] == b[both]))}, "
          f"later {int(np.sum(a[both] > b[both]))} (by {np.mean((a - b)[both & (a > b)]) if np.any(a[both] > b[both]) else 0:.2f} "
          f"on average), sooner {int(np.sum(a[both] < b[both]))}; the oracle only {int(np.sum(np.isfinite(b) & ~np.isfinite(a)))}, "
          f"the planner only {int(np.sum(np.isfinite(a) & ~np.isfinite(b)))}")
    print(f"bar (within 3 points at every tolerance, never above beyond the intervals): {'PASS' if ok else 'FAIL'}")
    return {"spec": spec, "task": task, "oracle_seconds": t_oracle, "planner_seconds": t_plan, "pass": ok}


def swimmer(states: int, workers: int, budget: PlannerBudget) -> None:
    prog = asap_dsl.load(SPECS / "swimmer.asap")
    t0 = time.perf_counter()
    reports = []
    for task in prog.tasks:
        t1 = time.perf_counter()
        asap = ir.to_text(prog.task(task).model.asap)  # as asapc oracle: a task before with this asap hands over
        warm = [w for r in reports if ir.to_text(prog.task(r.task).model.asap) == asap
                for w in shortest_sequences(r.results, budget.exchange)]
        done = [0]

        def progress(k: int, task=task, t1=t1) -> None:
            done[0] += k
            print(f"  {task}: {done[0]}/{states} states planned, {time.perf_counter() - t1:.0f} s", flush=True)

        reports.append(plan_states(prog, task, episodes=states, workers=workers, budget=budget, warm=warm,
                                   progress=progress))
        print(f"{task}: {time.perf_counter() - t1:.1f} s, pilot {reports[-1].extra['planner']['pilot_run']['steps']} "
              f"steps in {reports[-1].extra['planner']['pilot_run']['seconds']:.1f} s", flush=True)
    tighten_planned(prog, reports)
    print(f"\nswimmer, both tasks: {time.perf_counter() - t0:.1f} s on {workers} worker(s)")
    print("| task | states | within 50 | within 40 | within 30 | steps: min / 25% / median / 75% / max | time |")
    print("|---|---|---|---|---|---|---|")
    for rep in reports:
        d = rep.distribution()
        dist = " / ".join(f"{d[k]:g}" for k in ("min", "p25", "median", "p75", "max")) if d.get("reached") else "—"
        print(f"| {rep.task} | {len(rep.results)} | {_row(rep, 50)} | {_row(rep, 40)} | {_row(rep, 30)} | {dist} | "
              f"{rep.seconds:.0f} s |")
        print(f"  {rep.task} histogram: {json.dumps(d.get('histogram', {}))}; statuses {json.dumps(rep.counts())}; "
              f"tightened {rep.extra.get('tightened')}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--validate", action="store_true")
    ap.add_argument("--swimmer", action="store_true")
    ap.add_argument("--states", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--samples", type=int, default=PlannerBudget.samples)
    ap.add_argument("--iterations", type=int, default=PlannerBudget.iterations)
    args = ap.parse_args()
    budget = PlannerBudget(samples=args.samples, iterations=args.iterations)
    print(f"budget: {json.dumps(budget.to_dict())}")
    if args.validate:
        results = [validate("dc_motor.asap", "reach", args.states, args.workers, budget),
                   validate("bicycle.asap", "reach", args.states, args.workers, budget)]
        print("\nall:", "PASS" if all(r["pass"] for r in results) else "FAIL")
    if args.swimmer:
        swimmer(args.states, args.workers, budget)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
