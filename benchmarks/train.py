"""Training speed: wall time until each preset first comes within a margin of the oracle's ceiling.

For DC motor ``reach_avoid`` (by default), each variant trains in this process, one after the
other on the same machine, and every ``--every`` seconds of training its current policy is
evaluated on the 1000 seeded evaluation states (the clock stops while it is evaluated; it starts
when ``train`` is called, so the demonstrations' oracle, JAX's compilation and the environment's
build count). The first evaluation that comes within ``--margin`` points of the oracle's ceiling
at every tolerance gives the variant's time; the script prints the median times over the seeds and
their ratios against ``default``. This measures, it selects nothing: no model is kept.

The variants: ``default`` and ``paper`` (the presets as they are), and ``before16``: the default
preset as issue 16 found it (stable-baselines3 on torch, the numpy step, one gradient step after
every vector step, no demonstrations), and
``no-demos`` (the default without the oracle's demonstrations, to see what they bring). The
bars of issue 16: ``default`` at least 3x sooner than ``before16`` and 10x sooner than ``paper``
(a variant that never gets there counts as ``--limit``, so its ratio is a lower bound).

``--states validation`` judges on the 1000 validation states (seed 7, the oracle's ceiling on
them) instead: the states a choice between settings is made on, never the evaluation states.

    .venv/bin/python benchmarks/train.py [--task reach_avoid] [--margin 5] [--seeds 0,1,2]
        [--presets default,before16,paper] [--every 5] [--limit 600] [--states evaluation|validation]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import asap_dsl
from asap_dsl.rollout import Evaluator
from asap_dsl.sampling import EVAL_SEED, task_states

SPECS = Path(__file__).resolve().parents[1] / "specs"


# The default preset's settings as issue 16 found it: one gradient step after every vector step.
BEFORE16_SETTINGS = {"train_freq": 1, "gradient_steps": 1}
# variant -> (preset, training engine, step engine, demonstrations, settings); None: the preset's own
VARIANTS = {"default": ("default", None, None, None, None), "paper": ("paper", None, None, None, None),
            "before16": ("default", "sb3", "numpy", 0, BEFORE16_SETTINGS),
            "no-demos": ("default", None, None, 0, None)}
BARS = {"before16": 3.0, "paper": 10.0}


def _time_to_ceiling(spec: Path, task: str, variant: str, seed: int, ceiling: dict, margin: float, every: float,
                     limit: float, steps: int, log, n_envs=None, settings=None, state_seed: int = EVAL_SEED) -> dict:
    from stable_baselines3.common.callbacks import BaseCallback

    from asap_dsl.backends.rl.sb3 import PolicyController, Scaling
    from asap_dsl.backends.rl.config import resolve_config

    preset, engine, step, demos, own = VARIANTS[variant]
    settings = {**(own or {}), **(settings or {})} or None
    if step:
        os.environ["ASAP_ENGINE"] = step
    else:
        os.environ.pop("ASAP_ENGINE", None)
    prog = asap_dsl.load(spec)
    cfg = resolve_config(prog, task, preset=preset, seed=seed, steps=steps, n_envs=n_envs, settings=settings)
    tm = prog.task(task).model
    states = task_states(prog.system, tm, 1000, seed=state_seed)
    judge = Evaluator(prog, task, states, reward=cfg.reward)
    scaling = Scaling.for_system(prog.system, cfg.observation_scaling, cfg.action_scaling)
    out = {"preset": variant, "seed": seed, "seconds": None, "steps": None, "rates": None, "history": []}

    class Clock(BaseCallback):
        def __init__(self):
            super().__init__()
            self.paused = 0.0
            self.start = None
            self.next = every

        def _on_step(self) -> bool:
            now = time.perf_counter()
            clock = now - self.start - self.paused
            if clock < self.next:
                return True
            self.next = clock + every
            res = judge.run(PolicyController(self.model, scaling))
            rates = {T: res.rate(T) for T in ceiling}
            self.paused += time.perf_counter() - now
            out["history"].append((round(clock, 1), self.num_timesteps, rates))
            log(f"    {variant:<8} s{seed}  {clock:7.1f} s  {self.num_timesteps:>8,} steps  "
                + "  ".join(f"{T}: {100 * r:5.1f}%" for T, r in sorted(rates.items(), reverse=True)))
            if all(rates[T] >= ceiling[T] - margin / 100 for T in ceiling):
                out.update(seconds=round(clock, 1), steps=self.num_timesteps, rates=rates)
                return False
            return clock < limit

    clock = Clock()
    with tempfile.TemporaryDirectory() as tmp:
        clock.start = time.perf_counter()
        asap_dsl.train(prog, task, preset=preset, seed=seed, steps=steps, out=Path(tmp) / "run", evaluate=False,
                       callbacks=[clock], n_envs=n_envs, settings=settings, engine=engine, demonstrations=demos)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default=str(SPECS / "dc_motor.asap"))
    ap.add_argument("--task", default="reach_avoid")
    ap.add_argument("--margin", type=float, default=5.0, help="points below the ceiling that count (default 5)")
    ap.add_argument("--presets", default="default,before16,paper", help="variants: " + ", ".join(VARIANTS))
    ap.add_argument("--seeds", default="0", help="comma-separated training seeds (each preset, each seed)")
    ap.add_argument("--every", type=float, default=5.0, help="seconds of training between evaluations")
    ap.add_argument("--limit", type=float, default=600.0, help="give up after this much training (seconds)")
    ap.add_argument("--steps", type=int, default=2_000_000, help="step budget (the limit usually ends a run first)")
    ap.add_argument("--envs", type=int, default=None, help="environments of the default preset (to try others)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a hyperparameter of the default preset, e.g. batch_size=128 (to try others)")
    ap.add_argument("--states", choices=("evaluation", "validation"), default="evaluation",
                    help="judge on the evaluation states (seed 2024) or the validation states (seed 7)")
    args = ap.parse_args()
    from asap_dsl.backends.rl.config import VALIDATION_SEED

    state_seed = EVAL_SEED if args.states == "evaluation" else VALIDATION_SEED
    overrides = {}
    for item in args.set:
        key, _, value = item.partition("=")
        overrides[key.strip()] = json.loads(value)
    from asap_dsl.backends.oracle.cache import oracle_for

    prog = asap_dsl.load(args.spec)
    oracle = oracle_for(prog, args.task, state_seed, 1000, workers=2)
    if oracle is None:
        print("no oracle for this spec: nothing to measure against", file=sys.stderr)
        return 1
    tols = sorted(prog.task(args.task).model.tolerances, reverse=True)
    ceiling = {T: oracle.ceiling(T)["rate"] for T in tols}
    print(f"training benchmark: {Path(args.spec).name} {args.task}, {os.cpu_count()} CPUs; ceiling "
          + ", ".join(f"{T}: {100 * c:.1f}%" for T, c in ceiling.items())
          + f" on the {args.states} states (seed {state_seed})"
          + f"; target: within {args.margin:g} points at every tolerance; evaluation every {args.every:g} s")
    results = {}
    for preset in args.presets.split(","):
        if preset not in VARIANTS:
            print(f"unknown variant {preset!r} (known: {', '.join(VARIANTS)})", file=sys.stderr)
            return 2
    for preset in args.presets.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            tweak = preset in ("default", "no-demos")
            r = _time_to_ceiling(Path(args.spec), args.task, preset, seed, ceiling, args.margin, args.every,
                                 args.limit, args.steps, lambda m: print(m, flush=True),
                                 n_envs=args.envs if tweak else None, settings=overrides if tweak else None,
                                 state_seed=state_seed)
            results.setdefault(preset, []).append(r)
            got = "not reached" if r["seconds"] is None else f"{r['seconds']:.1f} s ({r['steps']:,} steps)"
            print(f"  {preset:<8} seed {seed}: {got}", flush=True)
    print()
    times = {}
    for preset, rs in results.items():
        t = [r["seconds"] for r in rs]
        if any(x is None for x in t):
            print(f"{preset:<8} did not get within {args.margin:g} points in {args.limit:g} s on every seed")
            times[preset] = None
        else:
            times[preset] = float(np.median(t))
            print(f"{preset:<8} median time to within {args.margin:g} points: {times[preset]:.1f} s over seeds "
                  f"{', '.join(str(r['seed']) for r in rs)}")
    failed = False
    for variant, bar in BARS.items():
        if variant not in times or not times.get("default"):
            continue
        other = times[variant] if times[variant] is not None else args.limit
        ratio = other / times["default"]
        bound = "" if times[variant] is not None else " (at least: it never got there)"
        ok = ratio >= bar
        failed |= not ok
        print(f"ratio {variant} / default: {ratio:.2f}x{bound} (bar: at least {bar:g}x) — {'PASS' if ok else 'FAIL'}")
    return 1 if failed or not times.get("default") else 0


if __name__ == "__main__":
    raise SystemExit(main())
