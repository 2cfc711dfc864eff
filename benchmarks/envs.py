"""Microseconds per vector step: the compiled step against what a user would use instead.

For each system, at batch 1, 8 and 64, side by side in one run (random actions, the
``reach_avoid`` task, every variant measured in interleaved rounds, the best round kept):

  compiled  make_vec_env(engine="native"): the whole step compiled (asap_dsl.native), through
            SB3's VecEnv interface (step_async + step_wait, info dicts included)
  arrays    the same compiled step without SB3's info dicts (AsapVecEnv.step_arrays): what the
            step itself costs; SB3's API adds a dict per entry and step, about 0.2 us each
  numpy     make_vec_env(engine="numpy"): the reference step, the same interface
  hand      a gymnasium env written by hand (benchmarks/hand_envs.py: the same ODE in Python
            floats, RK4 with 4 substeps, the two balls), as SB3 would run it: its step (and reset
            when an episode ends) at batch 1, DummyVecEnv above; "hand SB3" is DummyVecEnv at 1 too
  kernel    the dynamics alone as a numba kernel over the batch, called once per step

The bars (issue 16): at batch 1 the compiled step at least 2x faster than the hand-written env
(bicycle, attitude); at batch 8 an attitude step at most 30 us; every compiled step within 5x of
the dynamics kernel (the step itself, "arrays"; the ratio of the SB3 interface is printed beside). The swimmer's physics is MuJoCo: its "hand" is gymnasium's Swimmer-v5 and its
"kernel" the batched MuJoCo stepping alone (no bars: the physics dominates).
Usage: python benchmarks/envs.py [--seconds 0.25] [--rounds 5] [--only attitude] [--batches 1,8,64]
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import asap_dsl  # noqa: E402
from hand_envs import HandEnv, kernel  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SYSTEMS = ["dc_motor", "bicycle", "attitude", "swimmer"]
HAND_BAR = ("bicycle", "attitude")   # at batch 1: compiled at least 2x faster than by hand
KERNEL_BAR, HAND_RATIO, B8_US = 5.0, 2.0, 30.0


def _sb3(venv):
    def step(a):
        venv.step_async(a)
        return venv.step_wait()
    return step


def _single(env):
    env.reset(seed=0)

    def step(a):
        _, _, term, trunc, _ = env.step(a[0])
        if term or trunc:
            env.reset()
    return step


def _kernel_step(kern, x0):
    X = x0.copy()
    count = [0]

    def step(a):
        kern(X, a)
        count[0] += 1
        if count[0] % 30 == 0:  # an episode's length: the state stays where the dynamics are tame
            X[:] = x0
    return step


def _swimmer_peers(B):
    import gymnasium
    from stable_baselines3.common.vec_env import DummyVecEnv

    from asap_dsl.sim.mujoco_swimmer import MujocoSwimmer

    if B == 1:
        hand = _single(gymnasium.make("Swimmer-v5"))
    else:
        dv = DummyVecEnv([lambda: gymnasium.make("Swimmer-v5")] * B)
        dv.reset()
        hand = _sb3(dv)
    sim = MujocoSwimmer(B)
    sim.reset(np.zeros((B, 10)))
    return hand, None, (lambda a: sim.step(a))


def variants(name: str, B: int):
    """name -> step(actions) for each variant (None where it does not apply); compile info."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    path = ROOT / "specs" / f"{name}.asap"
    prog = asap_dsl.load(path)
    out, info = {}, ""
    for engine in ("native", "numpy"):
        venv = asap_dsl.make_vec_env(prog, "reach_avoid", num_envs=B, seed=0, engine=engine)
        venv.reset()
        out["compiled" if engine == "native" else "numpy"] = _sb3(venv)
        if engine == "native":
            out["arrays"] = venv.step_arrays
            core = venv.core
            info = f"{core.compile_seconds:.1f} s ({'cache' if core.compiled_from_cache else 'compiled'})"
    if name == "swimmer":
        out["hand"], out["hand SB3"], out["kernel"] = _swimmer_peers(B)
        return out, info
    dv = DummyVecEnv([lambda: HandEnv(name)] * B)
    dv.reset()
    out["hand"], out["hand SB3"] = (_single(HandEnv(name)), _sb3(dv)) if B == 1 else (_sb3(dv), None)
    x0 = asap_dsl.make_vec_env(prog, "reach_avoid", num_envs=B, seed=1, engine="numpy")
    x0.reset()
    out["kernel"] = _kernel_step(kernel(name, prog), np.ascontiguousarray(x0.core.states))
    return out, info


def measure(steps: dict, acts: list, seconds: float, rounds: int) -> dict:
    """Best and worst microseconds per step of each variant over interleaved rounds."""
    best = {k: (np.inf, 0.0) for k, f in steps.items() if f is not None}
    for f in steps.values():
        if f is not None:
            for a in acts[:4]:  # warm: compiled code loaded, caches filled
                f(a)
    for _ in range(rounds):
        for k, f in steps.items():
            if f is None:
                continue
            n, t0 = 0, time.perf_counter()
            while True:
                for a in acts:
                    f(a)
                n += len(acts)
                el = time.perf_counter() - t0
                if el >= seconds:
                    break
            us = el / n * 1e6
            lo, hi = best[k]
            best[k] = (min(lo, us), max(hi, us))
    return best


def _fmt(us) -> str:
    return f"{us:9.1f}" if us is not None and us < 1e4 else (f"{us:9.0f}" if us is not None else f"{'-':>9s}")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=0.25, help="length of one measured round per variant")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--only", default=None, help="the systems whose name contains this")
    ap.add_argument("--batches", default="1,8,64")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    batches = [int(b) for b in args.batches.split(",")]
    cols = ["compiled", "arrays", "numpy", "hand", "hand SB3", "kernel"]
    print(__doc__.split("Usage:")[0])
    print(f"{'system':9s} {'batch':>5s} " + " ".join(f"{c:>9s}" for c in cols)
          + f" | {'numpy/c':>8s} {'hand/c':>8s} {'c/kernel':>8s} {'a/kernel':>8s}  bars (us per step, best of "
          f"{args.rounds})")
    failed = 0
    for name in SYSTEMS:
        if args.only and args.only not in name:
            continue
        for B in batches:
            steps, info = variants(name, B)
            spec_env = asap_dsl.make_vec_env(ROOT / "specs" / f"{name}.asap", "reach_avoid", num_envs=B, engine="numpy")
            rng = np.random.default_rng(0)
            lo, hi = spec_env.action_space.low, spec_env.action_space.high
            acts = [rng.uniform(lo, hi, size=(B, lo.shape[0])).astype(np.float32) for _ in range(32)]
            res = measure(steps, acts, args.seconds, args.rounds)
            us = {k: res[k][0] if k in res else None for k in cols}
            c = us["compiled"]
            ratios = [us["numpy"] / c, us["hand"] / c, c / us["kernel"], us["arrays"] / us["kernel"]]
            bars = []
            if name != "swimmer":
                if B == 1 and name in HAND_BAR:
                    bars.append(("hand/c >= 2", ratios[1] >= HAND_RATIO))
                if B == 8 and name == "attitude":
                    bars.append(("<= 30 us", c <= B8_US))
                bars.append(("a/kernel <= 5", ratios[3] <= KERNEL_BAR))
            failed += sum(not ok for _, ok in bars)
            spread = max(res[k][1] / res[k][0] for k in res)
            text = " ".join(f"{what} {'PASS' if ok else 'FAIL'}" for what, ok in bars)
            print(f"{name:9s} {B:5d} " + " ".join(_fmt(us[k]) for k in cols)
                  + " | " + " ".join(f"{r:7.1f}x" if r is not None else f"{'-':>8s}" for r in ratios)
                  + f"  {text}  [spread {spread:.2f}; compile {info}]")
    print(f"\n{failed} bar(s) failed" if failed else "\nevery bar passed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
