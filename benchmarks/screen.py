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
- ``--failed-starts P`` and ``--demonstrations N``: the training's own settings (the default
  preset's rules, :mod:`asap_dsl.backends.rl.curriculum` and ``.demonstrations``; ``0`` and ``0``
  screen the default as it was before them). They were probes here first: the failed starts, and
  the oracle's longest sequences (then ``--long-demos N,L,R``: N states, sequences of L steps or
  more, each R times), measured before the rules were built.
- ``--sbx-class``: sbx's ``CrossQ`` or ``TQC`` in place of SAC (the SAC settings it accepts).
- ``--lr-drop AT,FACTOR``: after the share AT of the time limit, the learning rate times FACTOR.
- ``--action-search K,S,BETA,LOCAL``: SAC's actor also pulled towards the best of K candidate
  actions scored by the critics, on S states of each batch (:func:`patch_action_search`).
- ``--return-bound``: the critic's targets bounded below by the realised return (:func:`patch_return_bound`).
- ``--failed-demos EVERY,STATES,REPEAT,SECONDS``: the oracle's sequences for the latest failed
  starts go into the replay buffer as the run goes (:func:`patch_failed_demos`).
- ``--demo-bc BETA,FILTER``: SAC's actor also imitates the stored demonstrations (:func:`patch_demo_bc`).
- ``--observe-rho``: the observation also holds each atom's robustness (:func:`patch_observe_rho`).
- ``--steps N`` with ``--minutes 0``: a step budget instead of the clock (a loaded machine).
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
from functools import partial
from pathlib import Path

import numpy as np

import asap_dsl
from asap_dsl.backends.rl import presets, training
from asap_dsl.env import core_of


def patch_end_at_reach(bonus: float) -> dict:
    """The learner's episodes end at the first reach, that step earning ``bonus`` (the value of
    staying, ``r_sat / (1 - gamma)``); a wrapper right above the raw env, below the failed starts,
    so that the curriculum sees the episode end as reached. Returns the counters."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    from asap_dsl.backends.rl import curriculum

    stats = {"ended_at_reach": 0}

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
            reward[newly] = bonus
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
    training.failed_starts_env = lambda venv, share, seed: orig(EndAtReach(venv), share, seed)
    # The demonstrations' replays go through learner_env without the curriculum: the same rule there.
    orig_learner_env = training._Session.learner_env
    started = curriculum._failed_starts_class()

    def learner_env(self, raw):
        return orig_learner_env(self, raw if isinstance(raw, started) else EndAtReach(raw))

    training._Session.learner_env = learner_env
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


def patch_action_search(candidates: int, states: int, beta: float, local: float) -> None:
    """SAC's actor update with a search over actions: on ``states`` of the batch, ``candidates``
    actions (half uniform over [-1, 1]^m, half the mean action plus Gaussian noise of std ``local``)
    are scored by the critics; where the best scores above the policy's own mean action, the mean
    is pulled towards it (squared distance, weighted ``beta`` times the batch's mean |Q|, as
    TD3+BC normalises). The gradient of Q alone climbs the nearest hill of Q over actions; a
    better one elsewhere (reversing before turning) it never reaches."""
    import jax
    import jax.numpy as jnp
    import sbx

    from asap_dsl.backends.rl import engines

    base = sbx.SAC

    @jax.jit
    def update_actor(actor_state, qf_state, ent_coef_state, observations, key):
        key, dropout_key, noise_key, uni_key, loc_key = jax.random.split(key, 5)
        obs_s = observations[:states]
        mean_s = actor_state.apply_fn(actor_state.params, obs_s).mode()
        m = mean_s.shape[-1]
        k_uni = candidates // 2
        uni = jax.random.uniform(uni_key, (k_uni, states, m), minval=-1.0, maxval=1.0)
        loc = jnp.clip(mean_s[None] + local * jax.random.normal(loc_key, (candidates - k_uni, states, m)), -1.0, 1.0)
        cand = jnp.concatenate([uni, loc, mean_s[None]], axis=0)  # [K+1, S, m], the mean last
        kk = cand.shape[0]
        obs_rep = jnp.broadcast_to(obs_s[None], (kk,) + obs_s.shape).reshape(kk * states, -1)
        q = qf_state.apply_fn(qf_state.params, obs_rep, cand.reshape(kk * states, m), rngs={"dropout": dropout_key})
        q = jnp.min(q, axis=0).reshape(kk, states)
        best = jnp.argmax(q[:-1], axis=0)
        target = jnp.take_along_axis(cand[:-1], best[None, :, None], axis=0)[0]
        better = (jnp.max(q[:-1], axis=0) > q[-1]).astype(jnp.float32)
        target = jax.lax.stop_gradient(target)

        def actor_loss(params):
            dist = actor_state.apply_fn(params, observations)
            actor_actions = dist.sample(seed=noise_key)
            log_prob = dist.log_prob(actor_actions).reshape(-1, 1)
            qf_pi = qf_state.apply_fn(qf_state.params, observations, actor_actions, rngs={"dropout": dropout_key})
            min_qf_pi = jnp.min(qf_pi, axis=0)
            ent_coef_value = ent_coef_state.apply_fn({"params": ent_coef_state.params})
            sac_loss = (ent_coef_value * log_prob - min_qf_pi).mean()
            mean = actor_state.apply_fn(params, obs_s).mode()
            scale = jax.lax.stop_gradient(jnp.abs(min_qf_pi).mean())
            bc = (better * jnp.sum((mean - target) ** 2, axis=-1)).mean()
            return sac_loss + beta * scale * bc, -log_prob.mean()

        (actor_loss_value, entropy), grads = jax.value_and_grad(actor_loss, has_aux=True)(actor_state.params)
        actor_state = actor_state.apply_gradients(grads=grads)
        return actor_state, qf_state, actor_loss_value, key, entropy

    class SearchSAC(base):
        pass

    SearchSAC.update_actor = staticmethod(update_actor)
    orig_model_class = engines.SbxEngine._model_class

    def _model_class(self, algo):
        cls = orig_model_class(self, algo)
        return SearchSAC if algo == "sac" else cls

    engines.SbxEngine._model_class = _model_class


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


def patch_return_bound(gamma: float, tail: float) -> dict:
    """SAC's critic targets bounded below by the discounted return that followed each stored
    transition: ``max(r + gamma Q', G)``. The dynamics are deterministic, so every realised
    continuation (the learner's own episodes and the oracle's demonstrations) is a feasible one and
    ``G`` a true lower bound on the optimal ``Q`` (an episode cut by its length is completed with
    ``tail``, the least value any continuation has: the failure's floor for ever). What the
    learner once achieved from a hard state is never forgotten by its critic (Monte Carlo
    augmented actor-critic). Returns the counters."""
    import jax
    import jax.numpy as jnp
    import sbx
    from stable_baselines3.common.buffers import ReplayBuffer

    from asap_dsl.backends.rl import demonstrations, engines

    stats = {"episodes": 0, "bounded": 0}

    def ensure(buf):
        if getattr(buf, "mc", None) is None or buf.mc.shape != buf.rewards.shape:
            buf.mc = np.full(buf.rewards.shape, -np.inf, dtype=np.float32)
            buf.mc_rows = [[] for _ in range(buf.n_envs)]
            buf.mc_tracking = True

    orig_add = ReplayBuffer.add

    def add(self, obs, next_obs, action, reward, done, infos):
        ensure(self)
        row = self.pos
        orig_add(self, obs, next_obs, action, reward, done, infos)
        self.mc[row] = -np.inf
        if not self.mc_tracking:
            return
        for k in range(self.n_envs):
            self.mc_rows[k].append(row)
            if done[k]:
                # What follows the last step: the tail's bound after a time-out, nothing after a terminal.
                g = tail if infos[k].get("TimeLimit.truncated", False) else 0.0
                for r_ in reversed(self.mc_rows[k]):
                    g = float(self.rewards[r_, k]) + gamma * g
                    self.mc[r_, k] = g
                stats["episodes"] += 1
                self.mc_rows[k] = []

    ReplayBuffer.add = add
    orig_store = demonstrations.store

    def store(replay_buffer, tr):
        ensure(replay_buffer)
        n, T, pos0 = replay_buffer.n_envs, len(tr), replay_buffer.pos
        g = np.zeros(T, np.float64)
        nxt = 0.0
        for t in range(T - 1, -1, -1):
            if tr.dones[t]:
                nxt = float(tr.rewards[t]) + (gamma * tail if tr.timeouts[t] else 0.0)
            else:
                nxt = float(tr.rewards[t]) + gamma * nxt
            g[t] = nxt
        replay_buffer.mc_tracking = False
        try:
            slots = orig_store(replay_buffer, tr)
        finally:
            replay_buffer.mc_tracking = True
        rows = slots // n
        idx = np.arange(rows * n) % max(T, 1)
        for r in range(rows):
            replay_buffer.mc[(pos0 + r) % replay_buffer.buffer_size] = g[idx[r * n:(r + 1) * n]]
        return slots

    demonstrations.store = store

    @jax.jit
    def update_critic(actor_state, qf_state, ent_coef_state, observations, actions, next_observations, rewards,
                      dones, bound, key):
        key, noise_key, dropout_key_target, dropout_key_current = jax.random.split(key, 4)
        dist = actor_state.apply_fn(actor_state.params, next_observations)
        next_actions = dist.sample(seed=noise_key)
        next_log_prob = dist.log_prob(next_actions)
        ent_coef_value = ent_coef_state.apply_fn({"params": ent_coef_state.params})
        qf_next = qf_state.apply_fn(qf_state.target_params, next_observations, next_actions,
                                    rngs={"dropout": dropout_key_target})
        next_q = jnp.min(qf_next, axis=0) - ent_coef_value * next_log_prob[:, None]
        target = rewards[:, None] + (1 - dones[:, None]) * gamma * next_q
        target = jnp.maximum(target, bound[:, None])

        def mse(params, dropout_key):
            q = qf_state.apply_fn(params, observations, actions, rngs={"dropout": dropout_key})
            return 0.5 * ((target - q) ** 2).mean(axis=1).sum()

        loss, grads = jax.value_and_grad(mse)(qf_state.params, dropout_key_current)
        return qf_state.apply_gradients(grads=grads), (loss, ent_coef_value), key

    class BoundSAC(sbx.SAC):
        @classmethod
        @partial(jax.jit, static_argnames=["cls", "gradient_steps"])
        def _train_bound(cls, tau, target_entropy, gradient_steps, data, qf_state, actor_state, ent_coef_state, key):
            bs = data[0].shape[0] // gradient_steps

            def one(i, carry):
                qf_state, actor_state, ent_coef_state, key, info = carry
                b = [jax.lax.dynamic_slice_in_dim(x, i * bs, bs) for x in data]
                qf_state, (qf_loss, ent_value), key = update_critic(actor_state, qf_state, ent_coef_state, *b, key)
                qf_state = cls.soft_update(tau, qf_state)
                actor_state, qf_state, ent_coef_state, actor_loss, ent_loss, key = cls.update_actor_and_temperature(
                    actor_state, qf_state, ent_coef_state, b[0], target_entropy, key)
                return qf_state, actor_state, ent_coef_state, key, (actor_loss, qf_loss, ent_loss, ent_value)

            z = jnp.array(0.0)
            return jax.lax.fori_loop(0, gradient_steps, one, (qf_state, actor_state, ent_coef_state, key, (z, z, z, z)))

        def train(self, gradient_steps: int, batch_size: int) -> None:
            buf = self.replay_buffer
            ensure(buf)
            upper = buf.buffer_size if buf.full else buf.pos
            n = batch_size * gradient_steps
            inds = np.random.randint(0, upper, size=n)
            envs = np.random.randint(0, buf.n_envs, size=n)
            bound = buf.mc[inds, envs]
            stats["bounded"] += int(np.isfinite(bound).sum())
            data = (buf.observations[inds, envs], buf.actions[inds, envs], buf.next_observations[inds, envs],
                    buf.rewards[inds, envs].astype(np.float32),
                    (buf.dones[inds, envs] * (1 - buf.timeouts[inds, envs])).astype(np.float32),
                    bound.astype(np.float32))
            self._update_learning_rate(self.policy.actor_state.opt_state,
                                       learning_rate=self.lr_schedule(self._current_progress_remaining),
                                       name="learning_rate_actor")
            self._update_learning_rate(self.policy.qf_state.opt_state,
                                       learning_rate=self.initial_qf_learning_rate or self.lr_schedule(self._current_progress_remaining),
                                       name="learning_rate_critic")
            (self.policy.qf_state, self.policy.actor_state, self.ent_coef_state, self.key,
             (actor_loss, qf_loss, ent_loss, ent_value)) = self._train_bound(
                self.tau, self.target_entropy, gradient_steps, data, self.policy.qf_state, self.policy.actor_state,
                self.ent_coef_state, self.key)
            self._n_updates += gradient_steps
            self.logger.record("train/actor_loss", actor_loss.item())
            self.logger.record("train/critic_loss", qf_loss.item())
            self.logger.record("train/ent_coef", ent_value.item())

    orig_model_class = engines.SbxEngine._model_class
    engines.SbxEngine._model_class = lambda self, algo: BoundSAC if algo == "sac" else orig_model_class(self, algo)
    return stats


def patch_demo_bc(beta: float, q_filter: bool, batch: int = 256) -> dict:
    """SAC's actor also imitates the oracle's demonstrations: on ``batch`` demonstration pairs
    (observation, the oracle's action) drawn each step, the policy's mean is pulled towards the
    oracle's action (squared distance, weighted ``beta`` times the batch's mean |Q|, as TD3+BC
    normalises); with ``q_filter``, only where the critics score the oracle's action above the
    policy's own (Nair et al. 2018). The critic evaluates the policy it has: along an oracle's
    path it learns the oracle's value only once the policy takes the oracle's actions there.
    Returns the counters."""
    import jax
    import jax.numpy as jnp

    from asap_dsl.backends.rl import demonstrations, engines

    pairs: dict = {"obs": [], "act": []}
    stats = {"pairs": 0}
    orig_store = demonstrations.store

    def store(replay_buffer, tr):
        if len(tr):
            pairs["obs"].append(tr.obs)
            pairs["act"].append(np.clip(tr.actions, -0.97, 0.97))  # a tanh mean reaches +-1 only at infinity
            stats["pairs"] = sum(len(a) for a in pairs["act"])
        return orig_store(replay_buffer, tr)

    demonstrations.store = store

    def update_actor(actor_state, qf_state, ent_coef_state, observations, key):
        key, dropout_key, noise_key, pick_key = jax.random.split(key, 4)
        have = bool(pairs["obs"])  # read when traced: the demonstrations are stored before learning
        if have:
            d_obs = jnp.asarray(np.concatenate(pairs["obs"]))
            d_act = jnp.asarray(np.concatenate(pairs["act"]))
            idx = jax.random.randint(pick_key, (batch,), 0, d_obs.shape[0])
            o, a = d_obs[idx], d_act[idx]

        def actor_loss(params):
            dist = actor_state.apply_fn(params, observations)
            actor_actions = dist.sample(seed=noise_key)
            log_prob = dist.log_prob(actor_actions).reshape(-1, 1)
            qf_pi = qf_state.apply_fn(qf_state.params, observations, actor_actions, rngs={"dropout": dropout_key})
            min_qf_pi = jnp.min(qf_pi, axis=0)
            ent_coef_value = ent_coef_state.apply_fn({"params": ent_coef_state.params})
            loss = (ent_coef_value * log_prob - min_qf_pi).mean()
            if have:
                mean = actor_state.apply_fn(params, o).mode()
                w = jnp.ones(batch)
                if q_filter:
                    q_demo = jnp.min(qf_state.apply_fn(qf_state.params, o, a, rngs={"dropout": dropout_key}), axis=0)
                    q_own = jnp.min(qf_state.apply_fn(qf_state.params, o, jax.lax.stop_gradient(mean),
                                                      rngs={"dropout": dropout_key}), axis=0)
                    w = jax.lax.stop_gradient((q_demo[:, 0] > q_own[:, 0]).astype(jnp.float32))
                scale = jax.lax.stop_gradient(jnp.abs(min_qf_pi).mean())
                loss = loss + beta * scale * (w * jnp.sum((mean - a) ** 2, axis=-1)).mean()
            return loss, -log_prob.mean()

        (actor_loss_value, entropy), grads = jax.value_and_grad(actor_loss, has_aux=True)(actor_state.params)
        actor_state = actor_state.apply_gradients(grads=grads)
        return actor_state, qf_state, actor_loss_value, key, entropy

    orig_model_class = engines.SbxEngine._model_class
    made: dict = {}

    def _model_class(self, algo):
        cls = orig_model_class(self, algo)
        if algo != "sac":
            return cls
        if cls not in made:  # on top of any other probe's SAC (the return bound's critic)
            made[cls] = type("ImitatingSAC", (cls,), {"update_actor": staticmethod(jax.jit(update_actor))})
        return made[cls]

    engines.SbxEngine._model_class = _model_class
    return stats


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
    orig_init = training._Session.__init__

    def init(self, *a, **k):
        orig_init(self, *a, **k)
        holder["session"] = self

    training._Session.__init__ = init
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
    ap.add_argument("--action-search", help="CANDIDATES,STATES,BETA,LOCAL")
    ap.add_argument("--observe-rho", action="store_true")
    ap.add_argument("--return-bound", action="store_true")
    ap.add_argument("--failed-demos", help="EVERY,STATES,REPEAT,SECONDS")
    ap.add_argument("--demo-bc", help="BETA,FILTER (FILTER 1: only where the critics prefer the oracle's action)")
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
        stats = patch_end_at_reach(float(prog.task(args.task).model.r_sat_value) / (1.0 - gamma))
    if args.failure_times_deadline:
        patch_failure_reward()
    if args.sbx_class:
        patch_sbx_class(args.sbx_class)
    if args.return_bound:
        from asap_dsl.backends.rl.config import resolve_config

        cfg = resolve_config(prog, args.task)
        more = patch_return_bound(gamma, float(cfg.failure_reward))
    if args.observe_rho:
        patch_observe_rho(prog, args.task)
    if args.demo_bc:
        beta, filt = args.demo_bc.split(",")
        more["demo_bc"] = patch_demo_bc(float(beta), bool(int(filt)))
    if args.action_search:
        k, n, beta, local = args.action_search.split(",")
        patch_action_search(int(k), int(n), float(beta), float(local))
    kw = {k: getattr(args, k) for k in ("algo", "demonstrations", "failed_starts") if getattr(args, k) is not None}
    callbacks = []
    if args.lr_drop:
        at, factor = (float(v) for v in args.lr_drop.split(","))
        callbacks.append(lr_drop_callback(at * args.minutes * 60, factor))
    if args.failed_demos:
        e, n, r, sec = args.failed_demos.split(",")
        cb, fd_stats = patch_failed_demos(prog, args.task, int(e), int(n), int(r), float(sec))
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
