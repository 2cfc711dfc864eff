"""Screening a change to the default preset on the validation states (docs/training.md, "What has
not closed the last points").

A time-limited default training with one variant applied, then the mean of its last five
validations (500 validation states, seed 7: never the evaluation states). The variants are
measurement probes, not features: each patches the learner's environment or its model for this
process only, so that an idea can be judged in four minutes before it is built properly.

    .venv/bin/python benchmarks/screen.py specs/bicycle.asap --task reach_avoid --minutes 4 \\
        [--settings '{"gradient_steps": 2}'] [--algo td3] [--demonstrations 64] [--sbx-class TQC] \\
        [--failure-times-deadline] [--end-at-reach] [--failed-starts 0.5]

- ``--failure-times-deadline``: a failure step earns the reward's floor times the deadline.
- ``--end-at-reach``: the learner's episodes end at the first reach, that step earning ``r_sat / (1 - gamma)``.
- ``--failed-starts P`` and ``--demonstrations N``: the training's own settings (the default
  preset's rules, :mod:`asap_dsl.backends.rl.curriculum` and ``.demonstrations``; ``0`` and ``0``
  screen the default as it was before them). They were probes here first: the failed starts, and
  the oracle's longest sequences (then ``--long-demos N,L,R``: N states, sequences of L steps or
  more, each R times), measured before the rules were built.
- ``--sbx-class``: sbx's ``CrossQ`` or ``TQC`` in place of SAC (the SAC settings it accepts).
- ``--lr-drop AT,FACTOR``: after the share AT of the time limit, the learning rate times FACTOR.
- ``--preset-set NAME=VALUE`` (repeatable): a field of the default preset for this process, to
  screen a rule that is built but off (``failed_starts=0.25``, ``demonstration_repeat=2``).
"""

from __future__ import annotations

import argparse
import csv
import inspect
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import asap_dsl
from asap_dsl.backends.rl import presets, training
from asap_dsl.env import core_of


def patch_learner_env(end_at_reach_gamma: float) -> dict:
    """Wrap the learner's ``step_wait``: episodes end at the first reach; returns the counters."""
    stats = {"ended_at_reach": 0}
    orig = training._LearnerEnv.step_wait

    def step_wait(self):
        obs, reward, done, infos = orig(self)
        core = core_of(self.venv)
        newly = np.array([inf.get("t_reach") is not None and inf["t_reach"] == inf.get("t") and inf["t_reach"] > 0
                          and not d for inf, d in zip(infos, done)])
        if newly.any():
            inner = getattr(core, "inner", core)
            cand = core.states.copy()
            cand[newly] = inner._sample(int(newly.sum()))[0]
            for i in np.flatnonzero(newly):
                infos[i]["terminal_observation"] = obs[i].copy()
                infos[i]["TimeLimit.truncated"] = False
                reward[i] = inner.reward.r_sat / (1.0 - end_at_reach_gamma)
            obs[newly] = self.venv.scaling.observation(core.restart(newly, cand))
            done = done | newly
            stats["ended_at_reach"] += int(newly.sum())
        return obs, reward, done, infos

    training._LearnerEnv.step_wait = step_wait
    return stats


def patch_failure_reward() -> None:
    """A failure step earns the reward's floor times the deadline."""
    from asap_dsl import rewards

    orig = rewards.Reward.__init__

    def init(self, task, *a, **k):
        orig(self, task, *a, **k)
        if self.floor is not None:
            self.floor = self.floor * task.deadline

    rewards.Reward.__init__ = init


def lr_drop_callback(at_seconds: float, factor: float):
    """A callback that multiplies the learning rate by ``factor`` once ``at_seconds`` of wall time
    have passed (both engines read ``model.lr_schedule`` before each update)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class LrDrop(BaseCallback):
        def _on_training_start(self) -> None:
            self.t0, self.done = time.perf_counter(), False

        def _on_step(self) -> bool:
            if not self.done and time.perf_counter() - self.t0 >= at_seconds:
                lr = float(self.model.lr_schedule(1.0)) * factor
                self.model.lr_schedule = lambda _p: lr
                self.done = True
                print(f"learning rate now {lr:g} at {self.num_timesteps} steps", file=sys.stderr)
            return True

    return LrDrop()


def patch_sbx_class(name: str) -> None:
    import sbx

    from asap_dsl.backends.rl import engines
    from asap_dsl.backends.rl.sb3 import model_kwargs

    cls = getattr(sbx, name)
    accepted = set(inspect.signature(cls.__init__).parameters)

    def build(self, algo, env, settings, seed, tensorboard_log=None):
        engines._configure_jax()
        kw = {k: v for k, v in model_kwargs(algo, env.action_space, settings, self.name).items() if k in accepted}
        return cls("MlpPolicy", env, seed=seed, tensorboard_log=tensorboard_log, verbose=0, **kw)

    engines.SbxEngine.build = build
    engines.SbxEngine.load = lambda self, algo, path, env=None: cls.load(str(path), env=env, device="cpu")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec")
    ap.add_argument("--task", required=True)
    ap.add_argument("--minutes", type=float, default=4.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="runs/screen")
    ap.add_argument("--settings", type=json.loads, default=None)
    ap.add_argument("--algo")
    ap.add_argument("--demonstrations", type=int)
    ap.add_argument("--sbx-class", choices=("CrossQ", "TQC"))
    ap.add_argument("--failure-times-deadline", action="store_true")
    ap.add_argument("--end-at-reach", action="store_true")
    ap.add_argument("--failed-starts", type=float)
    ap.add_argument("--lr-drop", help="AT,FACTOR")
    ap.add_argument("--preset-set", action="append", default=[], metavar="NAME=VALUE")
    args = ap.parse_args()
    prog = asap_dsl.load(args.spec)
    if args.preset_set:
        fields = {}
        for item in args.preset_set:
            name, _, value = item.partition("=")
            fields[name] = type(getattr(presets.DEFAULT, name))(json.loads(value))
        presets.PRESETS["default"] = replace(presets.DEFAULT, **fields)
    gamma = presets.discount(prog.task(args.task).model.deadline, presets.DEFAULT.horizon)
    stats: dict = {}
    if args.end_at_reach:  # the plain default keeps its own step
        stats = patch_learner_env(gamma)
    if args.failure_times_deadline:
        patch_failure_reward()
    if args.sbx_class:
        patch_sbx_class(args.sbx_class)
    kw = {k: getattr(args, k) for k in ("algo", "demonstrations", "failed_starts") if getattr(args, k) is not None}
    callbacks = []
    if args.lr_drop:
        at, factor = (float(v) for v in args.lr_drop.split(","))
        callbacks.append(lr_drop_callback(at * args.minutes * 60, factor))
    t0 = time.time()
    res = asap_dsl.train(prog, args.task, steps=20_000_000, seed=args.seed, out=args.out, force=True,
                         time_limit=args.minutes * 60, evaluate=False, settings=args.settings, callbacks=callbacks,
                         **kw)
    rows = list(csv.DictReader(open(Path(args.out) / "curves.csv")))[-5:]
    last = [round(100 * sum(float(r[k]) for r in rows) / len(rows), 1) for k in sorted(
        (k for k in rows[0] if k.startswith("success_")), key=lambda k: int(k.split("_")[1]))]
    print(" ".join(sys.argv[1:]), json.dumps(stats), f"steps {res.steps} seconds {res.seconds:.0f} "
          f"wall {time.time() - t0:.0f}; mean of the last {len(rows)} validations (tightest first): {last}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
