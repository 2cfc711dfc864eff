"""The look-ahead (``asapc eval --lookahead N``) against the textbook rollout algorithm, in one run.

The peer is what one writes from Bertsekas' description: at every step, every state's candidates
rolled out with the policy after them to the deadline. Ours rolls each state's candidates only as
far as the reach they must beat, groups states of like reach, and skips states already decided.
Both refine the same policy on the same evaluation states (seed 2024); the script checks that they
reach at the same step from every state, and prints seconds and the ratio: PASS when the reach is the
same everywhere and ours is not slower.

    .venv/bin/python benchmarks/lookahead.py                        # a DC motor policy trained here (about a minute)
    .venv/bin/python benchmarks/lookahead.py --run RUN --states 1000  # a trained run, e.g. attitude's
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", help="a trained run directory (default: train a DC motor policy for --steps)")
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--states", type=int, default=300)
    ap.add_argument("--hold", type=int, default=8)
    args = ap.parse_args()
    import asap_dsl
    from asap_dsl.backends.compare.controllers import LookaheadController
    from asap_dsl.backends.rl.evaluation import load_run
    from asap_dsl.rollout import Evaluator
    from asap_dsl.sampling import task_states

    class Textbook(LookaheadController):
        """Every state, every candidate, to the deadline."""

        def _groups(self, t):
            idx = np.arange(len(self.due))
            return [(idx[lo:lo + self.chunk], self.deadline - t) for lo in range(0, len(idx), self.chunk)]

    with tempfile.TemporaryDirectory() as tmp:
        run = args.run
        if run is None:
            run = Path(tmp) / "run"
            asap_dsl.train(ROOT / "specs" / "dc_motor.asap", "reach_avoid", steps=args.steps, seed=0, out=run,
                           evaluate=False)
        loaded = load_run(run)
    prog, task = loaded.program, loaded.config.task
    states = task_states(prog.system, prog.task(task).model, args.states)
    ev = Evaluator(prog, task, states)
    seconds, reach = {}, {}
    for name, cls in (("textbook", Textbook), ("ours", LookaheadController)):
        c = cls(prog, loaded.controller(), task, hold=args.hold)
        start = time.perf_counter()
        reach[name] = ev.run(c).t_reach
        seconds[name] = time.perf_counter() - start
    policy = ev.run(loaded.controller()).t_reach
    same = np.array_equal(reach["textbook"], reach["ours"])
    print(f"look-ahead (holds up to {args.hold}), {Path(prog.file).name} {task}, {args.states} states: textbook "
          f"{seconds['textbook']:.1f} s, ours {seconds['ours']:.1f} s: {seconds['textbook'] / seconds['ours']:.2f}x; "
          f"same reach from every state: {same}; sooner than the policy from {int(np.sum(reach['ours'] < policy))} "
          f"states, later from {int(np.sum(reach['ours'] > policy))}")
    ok = same and seconds["ours"] <= seconds["textbook"]
    print(f"bar (the same choices, not slower): {'PASS' if ok else 'FAIL'}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
