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
- ``--end-at-reach``: the learner's episodes end at the first reach, that step earning ``r_sat / (1 - gamma)``
  (:func:`patch_end_at_reach`; the first probe of it left the restarted observations unscaled).
- ``--discounted-r-sat``: ``r_sat auto`` from the theorem's bound under the learner's discount,
  ``rho_max' + (gamma^-(k_max - 1) - 1) / (1 - gamma) + 1`` instead of ``rho_max' + k_max + 1``
  (:func:`patch_discounted_r_sat`). ``--discounted-r-sat-rho``: the same ratio of ``r_sat`` to the
  robustness's range at the reward's old scale: the robustness shrunk instead, ``r_sat`` as it was;
  ``--rho-factor F``: the robustness's scale times F (:func:`patch_rho_scale`).
- ``--reach-terminal AT``: after the share AT of the clock, every stored transition whose next state
  satisfies ``asap`` is drawn as terminal and worth ``r_sat / (1 - gamma)``: the critic's objective
  becomes the first arrival, the episodes and the data unchanged (:func:`patch_sample_rewards`).
  ``--rho-fade START,END,F``: the robustness part of every drawn reward times a factor going from 1
  at the share START of the clock to F at END (F 0: the shaping gone; ``d``: the discounted bound's
  ratio, ``(k_max + 1) / discounted_bound``).
- ``--failed-starts P`` and ``--demonstrations N``: the training's own settings (the default
  preset's rules, :mod:`asap_dsl.backends.rl.curriculum` and ``.demonstrations``; ``0`` and ``0``
  screen the default as it was before them). They were probes here first: the failed starts, and
  the oracle's longest sequences (then ``--long-demos N,L,R``: N states, sequences of L steps or
  more, each R times), measured before the rules were built.
- ``--sbx-class``: sbx's ``CrossQ`` or ``TQC`` in place of SAC (the SAC settings it accepts).
- ``--lr-drop AT,FACTOR``: after the share AT of the time limit, the learning rate times FACTOR.
- ``--entropy-drop AT,TARGET``: after the share AT of the time limit, SAC's target entropy TARGET per
  action dimension (the default's is -3): a narrower policy, whose mean the actor then optimises
  with less of its own noise around it.
- ``--action-search K,S,BETA,LOCAL``: SAC's actor also pulled towards the best of K candidate
  actions scored by the critics, on S states of each batch (:func:`patch_action_search`).
- ``--return-bound``: the critic's targets bounded below by the realised return (:func:`patch_return_bound`).
- ``--actor-ema TAU``: validation (and the kept model) judges an exponential moving average of the
  actor's parameters, moved TAU of the way after every train call (:func:`patch_actor_ema`).
- ``--critic-mean actor|both``: SAC's actor climbs the mean of its critics, not their minimum (``both``:
  their targets too, no clipped double-Q) (:func:`patch_critic_mean`).
- ``--failed-demos EVERY,STATES,REPEAT,SECONDS``: the oracle's sequences for the latest failed
  starts go into the replay buffer as the run goes (:func:`patch_failed_demos`).
- ``--demo-bc BETA,FILTER``: SAC's actor also imitates the stored demonstrations (:func:`patch_demo_bc`).
- ``--observe-rho``: the observation also holds each atom's robustness (:func:`patch_observe_rho`).
- ``--demo-paths FILE``: the run's demonstrations are every path of ``benchmarks/imitation.py``'s
  oracle cache (its training states, seed 31337; the oracle's seconds outside the clock), with
  ``--demonstrations N`` the first N of them (:func:`patch_demo_paths`); with ``--demo-bc`` the
  actor imitates all of them.
- ``--steps N`` with ``--minutes 0``: a step budget instead of the clock (a loaded machine).
- ``--preset-set NAME=VALUE`` (repeatable): a field of the default preset for this process, to
  screen a rule that is built but off (``failed_starts=0.25``, ``demonstration_repeat=2``).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from typing import Optional
from dataclasses import replace
from pathlib import Path

import numpy as np

import asap_dsl
from asap_dsl.backends.rl import presets
from asap_dsl.backends.rl import session as session_module
from asap_dsl.env import core_of
from learner_probes import (patch_action_search, patch_actor_ema, patch_critic_mean, patch_demo_bc,
                            patch_return_bound, patch_sbx_class)


def patch_end_at_reach(r_sat: float, gamma: float) -> dict:
    """The learner's episodes end at the first reach, that step earning the value of staying,
    ``r_sat / (1 - gamma)`` under the learner's current discount (the late rule lengthens it:
    the bonus and the stored bonuses follow); a wrapper right above the raw env, below the failed
    starts, so that the curriculum sees the episode end as reached. Returns the counters."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    from asap_dsl.backends.rl import curriculum

    stats = {"ended_at_reach": 0, "bonus": r_sat / (1.0 - gamma)}
    orig_discount = session_module.Session.set_discount

    def set_discount(self, model, new_gamma: float) -> None:
        orig_discount(self, model, new_gamma)
        was, stats["bonus"] = stats["bonus"], r_sat / (1.0 - float(new_gamma))
        buffer = getattr(model, "replay_buffer", None)
        if buffer is not None:
            buffer.rewards[buffer.rewards == np.float32(was)] = np.float32(stats["bonus"])

    session_module.Session.set_discount = set_discount

    class EndAtReach(VecEnvWrapper):
        def __init__(self, venv):
            super().__init__(venv)
            self.core = core_of(venv)

        def reset(self):
            return self.venv.reset()

        def step_wait(self):
            obs, reward, done, infos = self.venv.step_wait()
            newly = np.array([inf["t_reach"] is not None and inf["t_reach"] == inf["t"] and inf["t_reach"] > 0
                              and (not d or inf.get("TimeLimit.truncated", False))
                              for inf, d in zip(infos, done)])
            if not newly.any():
                return obs, reward, done, infos
            reward = np.array(reward, dtype=np.float64)
            reward[newly] = stats["bonus"]
            for i in np.flatnonzero(newly & done):  # reached on the last step: terminal, not a time-out
                infos[i]["TimeLimit.truncated"] = False
            live = newly & ~done
            if live.any():
                inner = getattr(self.core, "inner", self.core)
                cand = np.array(self.core.states, dtype=np.float64)
                cand[live] = inner._sample(int(live.sum()))[0]
                obs = np.array(obs)
                for i in np.flatnonzero(live):
                    infos[i]["terminal_observation"] = obs[i].copy()
                    infos[i]["TimeLimit.truncated"] = False
                obs[live] = self.core.restart(live, cand)
                done = done | live
            stats["ended_at_reach"] += int(newly.sum())
            return obs, reward, done, infos

    orig = curriculum.failed_starts_env
    session_module.failed_starts_env = lambda venv, share, seed: orig(EndAtReach(venv), share, seed)
    # The demonstrations' replays go through learner_env without the curriculum: the same rule there.
    orig_learner_env = session_module.Session.learner_env
    started = curriculum._failed_starts_class()

    def learner_env(self, raw):
        return orig_learner_env(self, raw if isinstance(raw, started) else EndAtReach(raw))

    session_module.Session.learner_env = learner_env
    return stats


def discounted_bound(gamma: float, k_max: int) -> float:
    """The theorem's ``r_sat - rho_max'`` with the discount kept in it (scaled units), ``+ 1`` as
    ``r_sat auto`` adds: ``(gamma^-(k_max - 1) - 1) / (1 - gamma) + 1`` (``k_max`` as gamma -> 1)."""
    return (gamma ** -(k_max - 1) - 1.0) / (1.0 - gamma) + 1.0


def patch_discounted_r_sat(gamma: float) -> float:
    """``r_sat auto`` from the theorem's bound with the discount kept in it. The paper's proof
    bounds the robustness a later arrival can gain by ``(rho_max - rho_min) k_max`` and the value of
    arriving a step sooner by ``r_sat - rho_max``; with discounting the first is a sum of ``gamma^t``
    over the steps before the arrival and the second is discounted by ``gamma^t3``, so a reward that
    prefers the sooner arrival needs ``r_sat > rho_max' + (gamma^-(k_max - 1) - 1) / (1 - gamma)``
    (scaled units, ``rho_max' - rho_min' = 1``): 203 instead of 31 at gamma 0.9 and k_max 30.
    Returns the value for a task of ``k_max`` 30 (for the log)."""
    from asap_dsl import model as model_module

    cls = model_module.TaskModel
    orig = cls.r_sat_value

    def r_sat_value(self) -> float:
        if self.r_sat is not None:
            return orig.fget(self)
        return orig.fget(self) - (self.k_max + 1) + discounted_bound(gamma, self.k_max)

    cls.r_sat_value = property(r_sat_value)
    return discounted_bound(gamma, 30)


def patch_rho_scale(factor) -> float:
    """The robustness's scale (and with it the floor) times ``factor(k_max)``, ``r_sat auto``
    following the scale (``rho_max' + k_max + 1``): the shaping before the goal weighs more (> 1)
    or less (< 1) against ``r_sat``. Returns the factor for a task of ``k_max`` 30."""
    from asap_dsl import model as model_module

    cls = model_module.TaskModel
    orig = cls.rho_scale
    cls.rho_scale = property(lambda self: orig.fget(self) * factor(self.k_max))
    return factor(30)


def patch_sample_rewards(r_sat: float, gamma: float, seconds: float, terminal_at: Optional[float],
                         fade: Optional[tuple]) -> dict:
    """Rewards transformed as the replay buffer draws them (the stored ones stay as the env gave
    them): after ``terminal_at`` of the clock's ``seconds``, a transition into ``asap`` (its reward
    ``r_sat``) is terminal and earns ``r_sat / (1 - gamma)`` under the learner's current discount;
    with ``fade = (start, end, f)`` every other reward (the scaled robustness, the floor) is
    multiplied by a factor going linearly from 1 at ``start`` to ``f`` at ``end``. Returns the
    counters."""
    import torch as th

    from asap_dsl.backends.rl import buffers

    t0 = time.time()
    stats = {"gamma": gamma, "factor": 1.0, "terminal": False}
    orig_discount = session_module.Session.set_discount

    def set_discount(self, model, new_gamma: float) -> None:
        orig_discount(self, model, new_gamma)
        stats["gamma"] = float(new_gamma)

    session_module.Session.set_discount = set_discount
    orig = buffers.FlatReplayBuffer._get_samples
    sat_at = np.float32(r_sat) - 1e-3

    def get_samples(self, batch_inds, env=None):
        out = orig(self, batch_inds, env=env)
        share = (time.time() - t0) / seconds
        rew, done = out.rewards, out.dones
        sat = rew >= sat_at
        if fade is not None:
            start, end, f = fade
            w = min(max((share - start) / max(end - start, 1e-9), 0.0), 1.0)
            stats["factor"] = 1.0 + w * (f - 1.0)
            if stats["factor"] != 1.0:
                rew = th.where(sat, rew, rew * stats["factor"])
        if terminal_at is not None and share >= terminal_at:
            stats["terminal"] = True
            rew = th.where(sat, th.full_like(rew, r_sat / (1.0 - stats["gamma"])), rew)
            done = th.where(sat, th.ones_like(done), done)
        return out._replace(rewards=rew, dones=done)

    buffers.FlatReplayBuffer._get_samples = get_samples
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


def entropy_drop_callback(at_seconds: float, per_action: float):
    """A callback that sets SAC's target entropy to ``per_action`` per action dimension once
    ``at_seconds`` of wall time have passed (sbx passes it to each update as an array)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class EntropyDrop(BaseCallback):
        def _on_training_start(self) -> None:
            self.t0, self.done = time.perf_counter(), False

        def _on_step(self) -> bool:
            if not self.done and time.perf_counter() - self.t0 >= at_seconds:
                self.model.target_entropy = float(per_action * np.prod(self.model.action_space.shape))
                self.done = True
                print(f"target entropy now {self.model.target_entropy:g} at {self.num_timesteps} steps", file=sys.stderr)
            return True

    return EntropyDrop()


def patch_observe_rho(prog, task: str) -> None:
    """The policy and critics also see the robustness of every atom of ``asap`` and ``avoid`` at
    the current state (a signed distance to each region, divided by a tenth of its range over the
    state space): the goal's boundary, where the value of a minimum-time problem jumps, is then a
    threshold on one input instead of a curved surface the networks must learn. Patched into the
    one scaling every path shares (training, validation, evaluation, demonstrations)."""
    from asap_dsl.model import formula_bounds
    from asap_dsl.stl import ir

    from asap_dsl.backends.rl import sb3

    tm = prog.task(task).model
    atoms = []
    for node in (tm.asap, tm.avoid):
        stack = [node] if node is not None else []
        while stack:
            x = stack.pop()
            if isinstance(x, ir.Atom):
                lo, hi = formula_bounds(x)
                width = (hi - lo) if np.isfinite(hi - lo) and hi > lo else 1.0
                atoms.append((x, 10.0 / width))
            else:
                stack.extend(ir.children(x))
    n, k = prog.system.n_state, len(atoms)
    orig_obs, orig_space = sb3.Scaling.observation, sb3.Scaling.observation_space

    def observation(self, obs):
        o = orig_obs(self, obs)
        raw = np.asarray(obs, dtype=np.float64)
        flat = raw.reshape(-1, raw.shape[-1])[:, :n]
        feats = np.stack([np.clip(a.robustness(flat) * c, -10.0, 10.0) for a, c in atoms], axis=-1)
        return np.concatenate([o, feats.reshape(o.shape[:-1] + (k,)).astype(np.float32)], axis=-1)

    def observation_space(self, space):
        from gymnasium import spaces

        b = orig_space(self, space)
        return spaces.Box(np.concatenate([b.low, np.full(k, -10, np.float32)]),
                          np.concatenate([b.high, np.full(k, 10, np.float32)]), dtype=np.float32)

    sb3.Scaling.observation, sb3.Scaling.observation_space = observation, observation_space


def patch_failed_demos(prog, task: str, every: int, states: int, repeat: int, state_seconds: float):
    """Every ``every`` steps, the oracle solves up to ``states`` of the failed starts (initial
    states of training episodes that did not reach: the curriculum's pool, the latest first) and
    their sequences, ``repeat`` times each, go into the replay buffer: demonstrations of exactly
    the manoeuvres the learner is missing, while it misses them (in the learner's process, its
    seconds counted as the run's). Returns the callback and its counters."""
    from stable_baselines3.common.callbacks import BaseCallback

    from asap_dsl.backends.oracle.solver import run as run_oracle
    from asap_dsl.backends.rl.demonstrations import Witnesses, add_demonstrations

    stats = {"failed_demo_calls": 0, "failed_demo_solved": 0, "failed_demo_seconds": 0.0}
    holder = {}
    orig_init = session_module.Session.__init__

    def init(self, *a, **k):
        orig_init(self, *a, **k)
        holder["session"] = self

    session_module.Session.__init__ = init
    kmax = prog.task(task).model.episode[1]

    class FailedDemos(BaseCallback):
        def _on_training_start(self) -> None:
            self.next_at = self.num_timesteps + every

        def _on_step(self) -> bool:
            if self.num_timesteps < self.next_at:
                return True
            self.next_at += every
            session = holder["session"]
            pool = [] if session.curriculum is None else session.curriculum.pool
            if not pool:
                return True
            t0 = time.perf_counter()
            chosen = np.stack(pool[-states:])
            report = run_oracle(prog, task, states=chosen, workers=1, time_limit=state_seconds)
            usable = [r for r in report.results
                      if r.status == "solved" and r.actions is not None and 1 <= len(r.actions) <= kmax]
            stats["failed_demo_calls"] += 1
            stats["failed_demo_solved"] += len(usable)
            if usable:
                starts = np.stack([np.asarray(r.x0, float) for r in usable for _ in range(repeat)])
                seqs = [np.asarray(r.actions, float) for r in usable for _ in range(repeat)]
                w = Witnesses(0, len(chosen), starts, seqs, np.full(len(seqs), kmax, np.int64))
                add_demonstrations(prog, task, self.model, session.learner_env, session.scaling, w,
                                   reward=session.cfg.reward, failure_reward=session.cfg.failure_reward)
            stats["failed_demo_seconds"] += time.perf_counter() - t0
            return True

    return FailedDemos(), stats


def patch_demo_paths(path: str, deadline: int) -> None:
    """The run's demonstration search replaced by the paths in ``path`` (a pickle of
    benchmarks/imitation.py: the oracle's results on its training and test states; the training
    states' are used, the first ``count`` the run asks for), each replayed once over the deadline."""
    import pickle

    from asap_dsl.backends.rl import demonstrations

    train, _ = pickle.loads(Path(path).read_bytes())

    def solve(prog, task, count, run_seed, **_):
        done = [r for r in train[:int(count)] if r.actions is not None and len(r.actions) > 0]
        return demonstrations.Witnesses(31337, int(count), np.stack([r.x0 for r in done]),
                                        [np.asarray(r.actions, float) for r in done],
                                        np.full(len(done), deadline, np.int64))

    demonstrations.solve = solve


def fraction_or_d(text: str):
    """A number, or ``d`` (the discounted bound's ratio, for ``--rho-fade``)."""
    return text if text == "d" else float(text)


def comma(*kinds):
    """An argparse type: comma-separated values, one of each kind in order (``--lr-drop 0.5,0.1``);
    a wrong count or value is argparse's one-line usage error, not a traceback."""
    def parse(text: str) -> tuple:
        parts = text.split(",")
        if len(parts) != len(kinds):
            raise argparse.ArgumentTypeError(f"expected {len(kinds)} comma-separated values, got {text!r}")
        try:
            return tuple(kind(p) for kind, p in zip(kinds, parts))
        except ValueError:
            said = {float: "a number", int: "a whole number", fraction_or_d: "a number or d"}
            raise argparse.ArgumentTypeError(f"expected {', '.join(said[k] for k in kinds)}; got {text!r}") from None
    return parse


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
    ap.add_argument("--discounted-r-sat", action="store_true")
    ap.add_argument("--discounted-r-sat-rho", action="store_true")
    ap.add_argument("--rho-factor", type=float, help="the robustness's scale times F, r_sat auto following it")
    ap.add_argument("--reach-terminal", type=float, metavar="AT")
    ap.add_argument("--rho-fade", metavar="START,END,F", type=comma(float, float, fraction_or_d))
    ap.add_argument("--failed-starts", type=float)
    ap.add_argument("--lr-drop", help="AT,FACTOR", type=comma(float, float))
    ap.add_argument("--entropy-drop", help="AT,TARGET per action dimension", type=comma(float, float))
    ap.add_argument("--preset-set", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--action-search", help="CANDIDATES,STATES,BETA,LOCAL", type=comma(int, int, float, float))
    ap.add_argument("--observe-rho", action="store_true")
    ap.add_argument("--demo-paths", help="an oracle cache of benchmarks/imitation.py")
    ap.add_argument("--return-bound", action="store_true")
    ap.add_argument("--actor-ema", type=float, metavar="TAU",
                    help="validation judges an average of the actor's parameters, moved TAU per train call")
    ap.add_argument("--critic-mean", choices=("actor", "both"),
                    help="the actor (both: and the critics' targets) take the critics' mean, not their minimum")
    ap.add_argument("--failed-demos", help="EVERY,STATES,REPEAT,SECONDS", type=comma(int, int, int, float))
    ap.add_argument("--demo-bc", help="BETA,FILTER (FILTER 1: only where the critics prefer the oracle's action)",
                    type=comma(float, int))
    ap.add_argument("--steps", type=int, default=20_000_000, help="a step budget (with --minutes 0: none)")
    args = ap.parse_args()
    prog = asap_dsl.load(args.spec)
    # A screen compares variants over the same clock: no run ends early on the plateau rule
    # (``--preset-set plateau=0.5`` puts it back).
    presets.PRESETS["default"] = replace(presets.DEFAULT, plateau=None)
    if args.preset_set:
        fields = {}
        for item in args.preset_set:
            name, _, value = item.partition("=")
            fields[name] = json.loads(value) if getattr(presets.DEFAULT, name) is None else \
                type(getattr(presets.DEFAULT, name))(json.loads(value))
        presets.PRESETS["default"] = replace(presets.PRESETS["default"], **fields)
    gamma = presets.discount(prog.task(args.task).model.deadline, presets.DEFAULT.horizon)
    stats: dict = {}
    more: dict = {}
    if args.end_at_reach:  # the plain default keeps its own step
        stats = patch_end_at_reach(float(prog.task(args.task).model.r_sat_value), gamma)
    if args.failure_times_deadline:
        patch_failure_reward()
    if args.discounted_r_sat:
        more["r_sat_above_rho_max"] = patch_discounted_r_sat(gamma)
    if args.discounted_r_sat_rho:
        more["rho_scaled_by"] = patch_rho_scale(lambda k: (k + 1) / discounted_bound(gamma, k))
    if args.rho_factor:
        more["rho_scaled_by"] = patch_rho_scale(lambda k: args.rho_factor)
    if args.reach_terminal is not None or args.rho_fade:
        fade = None
        if args.rho_fade:
            a, b, f = args.rho_fade
            k = prog.task(args.task).model.k_max
            fade = (a, b, (k + 1) / discounted_bound(gamma, k) if f == "d" else f)
        more["sampled"] = patch_sample_rewards(float(prog.task(args.task).model.r_sat_value), gamma,
                                               args.minutes * 60, args.reach_terminal, fade)
    if args.sbx_class:
        patch_sbx_class(args.sbx_class)
    if args.return_bound:
        from asap_dsl.backends.rl.config import resolve_config

        cfg = resolve_config(prog, args.task)
        more = patch_return_bound(gamma, float(cfg.failure_reward))
    if args.observe_rho:
        patch_observe_rho(prog, args.task)
    if args.demo_paths:
        patch_demo_paths(args.demo_paths, int(prog.task(args.task).model.deadline))
    if args.demo_bc:
        beta, filt = args.demo_bc
        more["demo_bc"] = patch_demo_bc(beta, bool(filt))
    if args.action_search:
        patch_action_search(*args.action_search)
    if args.actor_ema:
        more["actor_ema"] = patch_actor_ema(args.actor_ema)
    if args.critic_mean:
        more.update(patch_critic_mean(args.critic_mean == "both"))
    kw = {k: getattr(args, k) for k in ("algo", "demonstrations", "failed_starts") if getattr(args, k) is not None}
    callbacks = []
    if args.lr_drop:
        at, factor = args.lr_drop
        callbacks.append(lr_drop_callback(at * args.minutes * 60, factor))
    if args.entropy_drop:
        at, target = args.entropy_drop
        callbacks.append(entropy_drop_callback(at * args.minutes * 60, target))
    if args.failed_demos:
        cb, fd_stats = patch_failed_demos(prog, args.task, *args.failed_demos)
        callbacks.append(cb)
        more["failed_demos"] = fd_stats
    t0 = time.time()
    res = asap_dsl.train(prog, args.task, steps=args.steps, seed=args.seed, out=args.out, force=True,
                         time_limit=args.minutes * 60 or None, evaluate=False, settings=args.settings, callbacks=callbacks,
                         **kw)
    rows = list(csv.DictReader(open(Path(args.out) / "curves.csv")))[-5:]
    last = [round(100 * sum(float(r[k]) for r in rows) / len(rows), 1) for k in sorted(
        (k for k in rows[0] if k.startswith("success_")), key=lambda k: int(k.split("_")[1]))]
    print(" ".join(sys.argv[1:]), json.dumps({**stats, **more}), f"steps {res.steps} seconds {res.seconds:.0f} "
          f"wall {time.time() - t0:.0f}; mean of the last {len(rows)} validations (tightest first): {last}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
