"""Where a trained policy loses the step it arrives late by: at its last action, or along the path?

The default's policies arrive about one step after the oracle's minimum (docs/training.md, "Where
the step goes, along the path"). If the step were the last action's — a smooth law that does not
dare the grazing entry the oracle makes — then from the policy's own state k + 1 steps before its
arrival, some action held for k steps would enter the goal a step sooner. This script rolls the
run's policy out from ``--states`` initial states (seed 4242 by default: neither the evaluation
seed nor the validation seed), and from each state it reached in at least k + 1 steps tries every
action of a grid (``--levels`` levels per action coordinate, the bounds included), held k steps,
on the same simulator, for each k of ``--back``. It prints the share of states where one does.
A small share says the policy's path is slower all along, which a held action and the policy
after it (``asapc eval --lookahead``) recover in part and a sharper last step cannot.

    .venv/bin/python benchmarks/late_steps.py RUN [--states 300] [--levels 9] [--back 1,2,3]

Measured on runs with layer-normalised critics (docs/training.md, "Smooth activations and the critics'
mean"): attitude ``reach_avoid`` (a 9 x 9 x 9 grid) 11.1 / 11.2 / 7.2% for k = 1 / 2 / 3, the quadrotor
``reach`` (41 x 41) 9.0 / 9.0 / 6.0%.
"""

from __future__ import annotations

import argparse
import itertools
import sys

import numpy as np

#: How many simulator rows one batch may hold (states times grid actions).
MAX_ROWS = 2_000_000


class Held:
    """A controller that holds one given action per row."""

    def __init__(self, actions: np.ndarray):
        self.actions = actions

    def reset(self, states: np.ndarray) -> None:
        pass

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        return self.actions


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="a trained run directory")
    ap.add_argument("--states", type=int, default=300)
    ap.add_argument("--seed", type=int, default=4242)
    ap.add_argument("--levels", type=int, default=9, help="grid levels per action coordinate (at least 2)")
    ap.add_argument("--back", default="1,2,3", help="k: held for k steps from k + 1 steps before the arrival")
    args = ap.parse_args()
    from asap_dsl.backends.rl.config import VALIDATION_SEED
    from asap_dsl.backends.rl.evaluation import load_run
    from asap_dsl.rollout import Evaluator
    from asap_dsl.runs import RunError
    from asap_dsl.sampling import EVAL_SEED, task_states

    try:
        backs = sorted({int(k) for k in args.back.split(",")})
    except ValueError:
        backs = []
    if not backs or backs[0] < 1 or args.levels < 2 or args.states < 1:
        print("late_steps: --back takes whole numbers of at least 1, --levels at least 2, --states at least 1",
              file=sys.stderr)
        return 2
    if args.seed in (EVAL_SEED, VALIDATION_SEED):
        print(f"late_steps: seed {args.seed} is the evaluation's or the validation's; take another", file=sys.stderr)
        return 2
    try:
        loaded = load_run(args.run)
    except RunError as err:
        print(f"late_steps: {err}", file=sys.stderr)
        return 1
    prog, task = loaded.program, loaded.config.task
    low, high = prog.system.action_low, prog.system.action_high
    grid = np.array(list(itertools.product(*[np.linspace(lo, hi, args.levels) for lo, hi in zip(low, high)])))
    if len(grid) * args.states > MAX_ROWS:
        print(f"late_steps: {len(grid)} grid actions times {args.states} states is over {MAX_ROWS:,} rows; "
              "take fewer --levels or --states", file=sys.stderr)
        return 2
    states = task_states(prog.system, prog.task(task).model, args.states, seed=args.seed)
    res = Evaluator(prog, task, states).run(loaded.controller(), record=True)
    arrival = res.t_reach
    print(f"{args.run}: the policy within {', '.join(str(k) for k in prog.task(task).model.tolerances)}: "
          + " / ".join(f"{100 * res.rate(k):.1f}%" for k in prog.task(task).model.tolerances)
          + f" of {args.states} states (seed {args.seed}); a grid of {len(grid)} actions")
    for k in backs:
        idx = np.where(np.isfinite(arrival) & (arrival >= k + 1))[0]
        if len(idx) == 0:
            print(f"k = {k}: no state reached in {k + 1} steps or more")
            continue
        start = res.trajectories[idx, (arrival[idx] - k - 1).astype(int)]
        rows = np.repeat(start, len(grid), axis=0)
        held = Evaluator(prog, task, rows, steps=k).run(Held(np.tile(grid, (len(start), 1))))
        sooner = np.isfinite(held.t_reach).reshape(len(start), len(grid)).any(axis=1)
        print(f"k = {k}: from {k + 1} steps before the policy's arrival, a grid action held {k} step(s) enters "
              f"a step sooner on {100 * sooner.mean():.1f}% of {len(start)} states")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
