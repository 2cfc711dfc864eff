"""Screening a change to the default preset on the validation states (docs/training.md, "What has
not closed the last points").

A time-limited default training with one variant applied, then the mean of its last five
validations (500 validation states, seed 7: never the evaluation states). The variants are
measurement probes, not features: each patches the learner's environment or its model for this
process only, so that an idea can be judged in four minutes before it is built properly.

    .venv/bin/python benchmarks/screen.py specs/bicycle.asap --task reach_avoid --minutes 4 \\
        [--settings '{"gradient_steps": 2}'] [--algo td3] [--demonstrations 64] [--sbx-class TQC] \\
        [--failure-times-deadline] [--end-at-reach] [--failed-starts 0.5] [--long-demos 300,18,4]

- ``--failure-times-deadline``: a failure step earns the reward's floor times the deadline.
- ``--end-at-reach``: the learner's episodes end at the first reach, that step earning ``r_sat / (1 - gamma)``.
- ``--failed-starts P``: a new episode starts, with probability P, from the initial state of an
  earlier training episode that did not reach (drawn and removed from a buffer of 2000).
- ``--long-demos N,L,R``: the oracle on N states of the run's demonstration seed (before the clock,
  not counted), the sequences of at least L steps, each R times in the replay buffer first.
- ``--sbx-class``: sbx's ``CrossQ`` or ``TQC`` in place of SAC (the SAC settings it accepts).
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


def _core(venv):
    while not hasattr(venv, "core"):
        venv = venv.venv
    return venv.core


def _restart(wrapper, core, mask: np.ndarray, states: np.ndarray, obs: np.ndarray) -> None:
    """Start the masked entries at ``states`` with the episode lengths they have now, their first
    observations written into ``obs`` as the policy sees them (scaled)."""
    raw = np.empty(obs.shape, dtype=np.float32)
    core._start(states, np.asarray(core.k).copy(), mask, raw)
    obs[mask] = wrapper.venv.scaling.observation(raw)[mask]


def patch_learner_env(end_at_reach_gamma: float | None, failed_starts: float | None, seed: int) -> dict:
    """Wrap the learner's ``step_wait`` with the episode variants; returns their counters."""
    rng = np.random.default_rng(seed + 99)
    stats = {"episodes": 0, "failed": 0, "replayed": 0, "ended_at_reach": 0}
    buf: list = []
    starts: dict = {}
    orig = training._LearnerEnv.step_wait

    def step_wait(self):
        obs, reward, done, infos = orig(self)
        core = _core(self.venv)
        if end_at_reach_gamma is not None:
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
                _restart(self, core, newly, cand, obs)
                done = done | newly
                stats["ended_at_reach"] += int(newly.sum())
        if failed_starts is not None:
            st = starts.setdefault(id(core), core.states.copy())
            if done.any():
                idx = np.flatnonzero(done)
                for i in idx:
                    stats["episodes"] += 1
                    if infos[i].get("t_reach") is None:
                        buf.append(st[i].copy())
                        stats["failed"] += 1
                del buf[:-2000]
                take = np.zeros(core.B, dtype=bool)
                for i in idx:
                    take[i] = bool(buf) and rng.random() < failed_starts
                if take.any():
                    cand = core.states.copy()
                    for i in np.flatnonzero(take):
                        cand[i] = buf.pop(int(rng.integers(len(buf))))
                    _restart(self, core, take, cand, obs)
                    stats["replayed"] += int(take.sum())
                st[idx] = core.states[idx]
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


def patch_long_demos(prog, task: str, n: int, least: int, repeat: int) -> str:
    """The oracle's long sequences as the run's demonstrations; returns what was found."""
    from asap_dsl.backends.rl import demonstrations as D

    t0 = time.time()
    w = D.solve(prog, task, n, 0, workers=2, state_seconds=10.0)
    keep = [i for i, s in enumerate(w.sequences) if len(s) >= least]
    idx = [i for i in keep for _ in range(repeat)]
    w2 = replace(w, oracle_seconds=0.0, starts=w.starts[idx], sequences=[w.sequences[i] for i in idx],
                 lengths=w.lengths[idx])
    D.solve = lambda *a, **k: w2
    return f"oracle {time.time() - t0:.0f} s: {len(w.sequences)} solved, {len(keep)} of at least {least} steps"


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
    ap.add_argument("--long-demos", help="N,L,R")
    args = ap.parse_args()
    prog = asap_dsl.load(args.spec)
    told = []
    if args.long_demos:
        n, least, repeat = (int(v) for v in args.long_demos.split(","))
        told.append(patch_long_demos(prog, args.task, n, least, repeat))
        args.demonstrations = n
    gamma = presets.discount(prog.task(args.task).model.deadline, presets.DEFAULT.horizon)
    stats: dict = {}
    if args.end_at_reach or args.failed_starts is not None:  # the plain default keeps its own step
        stats = patch_learner_env(gamma if args.end_at_reach else None, args.failed_starts, args.seed)
    if args.failure_times_deadline:
        patch_failure_reward()
    if args.sbx_class:
        patch_sbx_class(args.sbx_class)
    kw = {k: getattr(args, k) for k in ("algo", "demonstrations") if getattr(args, k) is not None}
    t0 = time.time()
    res = asap_dsl.train(prog, args.task, steps=5_000_000, seed=args.seed, out=args.out, force=True,
                         time_limit=args.minutes * 60, evaluate=False, settings=args.settings, **kw)
    rows = list(csv.DictReader(open(Path(args.out) / "curves.csv")))[-5:]
    last = [round(100 * sum(float(r[k]) for r in rows) / len(rows), 1) for k in sorted(
        (k for k in rows[0] if k.startswith("success_")), key=lambda k: int(k.split("_")[1]))]
    print(" ".join(sys.argv[1:]), *told, json.dumps(stats), f"steps {res.steps} seconds {res.seconds:.0f} "
          f"wall {time.time() - t0:.0f}; mean of the last {len(rows)} validations (tightest first): {last}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
