"""Steps per second of the batched vector env against gymnasium's SyncVectorEnv over the single env.

Both run the same spec, task and reward with random actions, measured side by side in one run.
`batched` is AsapVecEnv.step (SB3 interface, info dicts included); `arrays` is step_arrays (no
info dicts); `sync` is gymnasium.vector.SyncVectorEnv of make_env (same-step autoreset).
The specs/ cases run ``--task`` (atom-only formulas: no online monitor); the double-integrator
``park`` case (``examples/``) has a past operator (``historically``), so its ``asap`` is tracked
by an online monitor that is reset per entry on autoreset.
Usage: python benchmarks/envs.py [--seconds 2] [--only park]  (--only: rows whose spec or task contains it)
"""

import argparse
import time
from pathlib import Path

import gymnasium
import numpy as np

import asap_dsl

ROOT = Path(__file__).resolve().parent.parent
SPECS, EXAMPLES = ROOT / "specs", ROOT / "examples"
# (spec file, task (None: --task), num_envs)
CASES = [(SPECS / "dc_motor.asap", None, 64), (SPECS / "dc_motor.asap", None, 1024),
         (SPECS / "attitude.asap", None, 64), (SPECS / "attitude.asap", None, 1024),
         (SPECS / "swimmer.asap", None, 64), (SPECS / "swimmer.asap", None, 256),
         (EXAMPLES / "double_integrator.asap", "park", 64), (EXAMPLES / "double_integrator.asap", "park", 1024)]


class _IntTReach(gymnasium.Wrapper):
    """``t_reach`` None -> -1: gymnasium's info batching cannot mix None and int in one key."""

    def reset(self, **kw):
        obs, info = self.env.reset(**kw)
        return obs, self._fix(info)

    def step(self, action):
        obs, r, term, trunc, info = self.env.step(action)
        return obs, r, term, trunc, self._fix(info)

    @staticmethod
    def _fix(info):
        if info.get("t_reach", 0) is None:
            info["t_reach"] = -1
        return info


def rate(step, n_envs, actions, seconds):
    step(actions[0])  # warm up
    steps, t0, i = 0, time.perf_counter(), 0
    while True:
        step(actions[i % len(actions)])
        steps += 1
        i += 1
        el = time.perf_counter() - t0
        if el >= seconds and steps >= 3:
            return steps * n_envs / el


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--task", default="reach_avoid")
    ap.add_argument("--only", default=None, help="run only the rows whose spec or task name contains this")
    args = ap.parse_args()
    print("env steps per second (summed over the entries), random actions:\n"
          "  batched  AsapVecEnv.step, the SB3 interface with its info dicts (what training uses)\n"
          "  arrays   AsapVecEnv.step_arrays, the same step returning arrays only (no info dicts built)\n"
          "  sync     gymnasium's SyncVectorEnv over single AsapEnvs (the peer)\n"
          "  ratio    batched / sync\n")
    print(f"{'spec':17s} {'task':12s} {'envs':>5s} {'batched':>12s} {'arrays':>12s} {'sync':>12s} {'ratio':>7s}")
    for path, task, n in CASES:
        task = task or args.task
        if args.only and args.only not in path.stem and args.only not in task:
            continue
        venv = asap_dsl.make_vec_env(path, task, num_envs=n, seed=0)
        venv.reset()
        rng = np.random.default_rng(0)
        lo, hi = venv.action_space.low, venv.action_space.high
        actions = [rng.uniform(lo, hi, size=(n, lo.shape[0])).astype(np.float32) for _ in range(16)]
        batched = rate(venv.step, n, actions, args.seconds)
        arrays = rate(venv.step_arrays, n, actions, args.seconds)
        sync = gymnasium.vector.SyncVectorEnv([lambda: _IntTReach(asap_dsl.make_env(path, task)) for _ in range(n)],
                                              autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP)
        sync.reset(seed=0)
        s = rate(sync.step, n, actions, args.seconds)
        print(f"{path.stem:17s} {task:12s} {n:5d} {batched:12,.0f} {arrays:12,.0f} {s:12,.0f} {batched / s:6.1f}x")


if __name__ == "__main__":
    main()
