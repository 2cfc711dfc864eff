"""Per-env-step cost of the online formula trackers with autoreset, separate vs combined.

On every step an autoresetting vector env advances every tracker with the reached states and then
restarts the finished entries at their initial states. ``separate`` is ``tracker.step(states)`` then
``tracker.restart(done, cand)`` (atoms evaluated twice when an entry finished); ``combined`` is
``tracker.step_and_restart(states, done, cand)`` (atoms evaluated once on the reached states and
the restart states together, then the two window updates). Both run in the same process on the
same pre-drawn states and done masks (each entry finishes with probability 1/70 per step, as the
60..80-step episodes of ``park`` do); ``no done`` is the floor, the same steps with no entry ever
finishing (one monitor update per step). Times are microseconds per env step (best of --repeat).
Usage: python benchmarks/monitors.py [--steps 2000] [--repeat 5]
"""

import argparse
import time
from pathlib import Path

import numpy as np

import asap_dsl
from asap_dsl.rewards import FormulaTracker

ROOT = Path(__file__).resolve().parent.parent
CASES = [(ROOT / "examples" / "double_integrator.asap", "park", 64),
         (ROOT / "examples" / "double_integrator.asap", "park", 1024)]


def draw(system, B, steps, rng, p_done=1 / 70):
    lo, hi = system.init_low, system.init_high
    lo_s, hi_s = system.state_low, system.state_high
    n = len(lo)
    states = rng.uniform(np.maximum(lo_s, -10), np.minimum(hi_s, 10), size=(steps, B, n))
    # slow runs now and then so `historically speed < 0.05` is sometimes true
    states[:, :, -1] *= np.where(rng.random((steps, B)) < 0.5, 1e-3, 1.0)
    done = rng.random((steps, B)) < p_done
    cand = rng.uniform(lo, hi, size=(steps, B, n))
    return states, done, cand


def run(tr, states, done, cand, combined):
    tr.restart_all(states[0])
    t0 = time.perf_counter()
    for i in range(1, len(states)):
        if combined:
            tr.step_and_restart(states[i], done[i], cand[i])
        else:
            tr.step(states[i])
            tr.restart(done[i], cand[i])
    return (time.perf_counter() - t0) / (len(states) - 1) * 1e6


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    has_combined = hasattr(FormulaTracker, "step_and_restart")
    print(f"{'spec':17s} {'task':6s} {'B':>5s} {'no done':>9s} {'separate':>10s} {'combined':>10s} {'speedup':>8s}"
          "   (us per env step, asap tracker)")
    for path, task, B in CASES:
        prog = asap_dsl.load(path)
        tm = prog.task(task).model
        sysm = prog.system
        rng = np.random.default_rng(0)
        states, done, cand = draw(sysm, B, args.steps, rng)
        tr = FormulaTracker(tm.asap, B, sysm.n_state)
        floor, sep, com = [], [], []  # interleaved, so that machine noise hits all three alike
        for _ in range(args.repeat):
            floor.append(run(tr, states, np.zeros_like(done), cand, False))
            sep.append(run(tr, states, done, cand, False))
            if has_combined:
                com.append(run(tr, states, done, cand, True))
        floor, sep = min(floor), min(sep)
        head = f"{path.stem:17s} {task:6s} {B:5d} {floor:9.1f} {sep:10.1f}"
        if has_combined:
            com = min(com)
            print(f"{head} {com:10.1f} {sep / com:7.2f}x")
        else:
            print(f"{head} {'-':>10s}")


if __name__ == "__main__":
    main()
