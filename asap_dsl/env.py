"""A task of a spec as a gymnasium environment, single or truly batched, with the ASAP-Phi reward.

Episodes follow the paper's Algorithm 1 and 2 (docs/language.md, "Tasks"):

* ``reset``: the episode length ``k ~ U{kmin, ..., kmax}``, the initial state ``s0 ~ U(init box)``
  (redrawn while ``avoid`` holds at step 0; :func:`asap_dsl.sampling.initial_states`).
* ``step``: actions are clipped to the action bounds; the simulator advances one ``dt``.
  The episode then ends, in this order of precedence:
  ``non_finite`` (a NaN/inf state, a NaN robustness, or a reward beyond float32), ``avoid`` (``avoid`` holds), ``out_of_bounds`` (the state left
  the state space) — all three ``terminated`` (failure) — else ``time_limit`` at step ``k``
  (``truncated``). Reaching ``asap`` does not end the episode (the agent must stay).
* The observation is the state as float32, clipped into the state-space box (a terminal state
  outside it is clipped), plus with ``observe state, time`` the steps left over the deadline.
  A non-finite state is never observed: it is replaced by the last finite state (the state before
  the step), which the reward and the monitors also see.
* ``info``: ``rho`` (ρ of ``asap`` at the step), ``satisfied`` (``asap`` holds), ``t_reach`` (the first
  step at which ``asap`` held with no failure at that step, else None), ``end_reason`` (None while
  running, else one of ``END_REASONS``) and ``t`` (steps taken).
* Rewards: :mod:`asap_dsl.rewards` (the failure step earns the reward's floor; a non_finite
  step earns that floor, or 0 where the reward has none). Every reward, observation and ``info``
  value is finite.

``make_vec_env`` is an SB3 ``VecEnv`` that steps all entries at once in numpy, with autoreset of
finished entries (their ``info`` holds ``terminal_observation`` and ``TimeLimit.truncated``) and
per-entry episode lengths. ``step_arrays`` returns the raw arrays without building info dicts.
Both are views of one :class:`EnvCore` (the batched episodes: one ``step``, one place that
builds ``info``), which :class:`asap_dsl.rollout.Evaluator` drives too.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Optional, Union

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .rewards import FLOAT32_MAX, FormulaTracker, make_reward
from .registration import register_benchmarks, specs_dir
from .sampling import initial_states
from .native import with_engine
from .sim import build_simulator

__all__ = ["AsapEnv", "AsapVecEnv", "END_REASONS", "EnvCore", "core_of", "infos", "make_env", "make_vec_env", "register_envs"]

END_REASONS = (None, "avoid", "out_of_bounds", "non_finite", "time_limit")
_AVOID, _OOB, _NONFINITE, _TIME = 1, 2, 3, 4


def float32_bounds(bounds: np.ndarray) -> np.ndarray:
    """Bounds as float32, those beyond its range unbounded. (``copysign``, not ``sign * inf``:
    a bound of 0 would make NaN, and a warning, in the branch ``where`` discards.)"""
    bounds = np.asarray(bounds, dtype=np.float64)
    return np.where(np.abs(bounds) > FLOAT32_MAX, np.copysign(np.inf, bounds), bounds).astype(np.float32)


def _program(prog_or_path):
    from .program import Program, load

    if isinstance(prog_or_path, Program):
        return prog_or_path
    if isinstance(prog_or_path, (str, os.PathLike)):
        return load(prog_or_path)
    raise TypeError(f"expected a Program or the path of a .asap file; got {type(prog_or_path).__name__}")


class EnvCore:
    """The batched episodes of one task: ``batch`` entries stepped together in numpy.

    Shared by :class:`AsapEnv` (a batch of one), :class:`AsapVecEnv` and
    :class:`asap_dsl.rollout.Evaluator`. :meth:`reset_all` or :meth:`start` begins every entry's
    episode, :meth:`step` advances them all (with ``autoreset``, finished entries restart at
    once); after either, ``states``, ``t``, ``k`` (episode lengths), ``t_reach``, ``end`` and the
    trackers ``asap``/``avoid`` hold the batch's state, and :meth:`infos` the ``info`` of each
    entry for the last reset or step (before any autoreset).

    :param program: a checked :class:`asap_dsl.Program`
    :param task: the task's name (None: the only task); KeyError with a suggestion if unknown
    :param batch: the number of entries, at least 1
    :param reward: None (the task's own), a text such as ``"rho(window = 5)"``, or a RewardModel
    :param autoreset: restart finished entries within :meth:`step` (a vector env's contract)
    :param failure_reward: the reward of a failure step instead of the reward's floor
    """

    def __init__(self, program, task: Optional[str], batch: int, reward: Any, autoreset: bool,
                 failure_reward: Optional[float] = None):
        self.program = program
        self.task = program.task(task)  # KeyError with a suggestion on an unknown name
        tm = self.tm = self.task.model
        sysm = self.system = program.system
        if isinstance(batch, bool) or not float(batch).is_integer() or batch < 1:
            raise ValueError(f"num_envs must be a whole number, at least 1; got {batch!r}")
        self.B, self.n, self.autoreset = int(batch), sysm.n_state, autoreset
        self.reward = make_reward(tm, program.regions, self.n, self.B, reward, failure_reward, dt=sysm.dt)
        self.sim = build_simulator(sysm, self.B, program.file)
        # No episode (training: at most kmax steps; evaluation: the deadline) is longer than the
        # deadline: windows beyond it are capped, so monitors never hold more than an episode.
        from .stl.ir import cap_past_windows

        self.asap = FormulaTracker(cap_past_windows(tm.asap, tm.deadline), self.B, self.n)
        self.avoid = (FormulaTracker(cap_past_windows(tm.avoid, tm.deadline), self.B, self.n)
                      if tm.avoid is not None else None)
        trackers = [self.asap] + ([self.avoid] if self.avoid else []) + self.reward.trackers
        self.trackers = trackers
        # Stepped after ``done`` is known (which needs ``avoid`` only): with autoreset, these step and
        # restart in one call each (atoms evaluated once on the reached and the restart states).
        self._late = [self.asap] + self.reward.trackers
        lo, hi = tm.rho_bounds  # for info's finite ρ (computed once: bounds walk the formula)
        big = np.finfo(np.float64).max
        self._rho_lo, self._rho_hi = (lo if np.isfinite(lo) else -big), (hi if np.isfinite(hi) else big)
        self.kmin, self.kmax = tm.episode
        self.low, self.high = sysm.state_low, sysm.state_high
        self.observe_time = "time" in tm.observe
        low32, high32 = float32_bounds(self.low), float32_bounds(self.high)
        if self.observe_time:
            low32 = np.append(low32, np.float32(0.0))
            high32 = np.append(high32, np.float32(max(1.0, self.kmax / tm.deadline)))
        self.obs_low, self.obs_high = low32, high32
        self._clip_lo, self._clip_hi = np.maximum(self.low, -FLOAT32_MAX), np.minimum(self.high, FLOAT32_MAX)
        self.observation_space = spaces.Box(low32, high32, dtype=np.float32)
        self.action_space = spaces.Box(sysm.action_low.astype(np.float32), sysm.action_high.astype(np.float32),
                                       dtype=np.float32)
        self.rng = np.random.default_rng()
        self.states = np.zeros((self.B, self.n))
        self.t = np.zeros(self.B, dtype=np.int64)
        self.k = np.zeros(self.B, dtype=np.int64)
        self.t_reach = np.full(self.B, -1, dtype=np.int64)
        self.end = np.zeros(self.B, dtype=np.int64)
        self._keep_info(np.zeros(self.B), np.zeros(self.B, dtype=bool))
        # ``states [m, n] -> bool [m]``: where avoid holds at step 0 of fresh episodes (None: the
        # offline evaluator; the compiled core sets its own, which gives the same values).
        self.avoid_at_start = None

    # ---- helpers -----------------------------------------------------------------------------
    def _finite_rho(self, rho: np.ndarray) -> np.ndarray:
        """ρ for ``info``: NaN (the episode ended as non_finite) as 0; ±inf (an empty past window
        at the first steps) as the formula's bound, or the largest float where that is infinite."""
        return np.nan_to_num(rho, nan=0.0, posinf=self._rho_hi, neginf=self._rho_lo)


    def _keep_info(self, rho: np.ndarray, sat: np.ndarray) -> None:
        """What :func:`infos` reports for the reset or step just taken (kept apart from the live
        arrays, which an autoreset changes): ρ of ``asap`` made finite, its satisfaction, and the
        entries' ``t_reach``, ``end`` and ``t``."""
        self.info_rho = self._finite_rho(rho)
        self.info_sat = sat.copy()
        self.info_t_reach = self.t_reach.copy()
        self.info_end = self.end.copy()
        self.info_t = self.t.copy()

    def _sample(self, m: int):
        s0 = initial_states(self.system, m, self.rng, self.tm.avoid, box=self.tm.init_box, holds=self.avoid_at_start)
        k = self.rng.integers(self.kmin, self.kmax + 1, size=m)
        return s0, k

    def obs(self, states=None, t=None, k=None) -> np.ndarray:
        states = self.states if states is None else states
        o = np.clip(states, self._clip_lo, self._clip_hi).astype(np.float32)
        o = np.clip(o, self.obs_low[: self.n], self.obs_high[: self.n])
        if self.observe_time:
            t = self.t if t is None else t
            k = self.k if k is None else k
            left = np.clip((k - t) / self.tm.deadline, 0.0, self.obs_high[-1]).astype(np.float32)
            o = np.concatenate([o, left[:, None]], axis=1)
        return o

    def _set_states(self, s: np.ndarray, mask=None) -> np.ndarray:
        full = self.states.copy()
        if mask is None:
            full = s
        else:
            full[mask] = s[mask]
        out = self.sim.reset(full, mask=mask)
        if not np.allclose(out if mask is None else out[mask], full if mask is None else full[mask],
                           rtol=1e-9, atol=1e-9, equal_nan=True):
            raise self.sim._fail("reset did not set the states it was given (the protocol requires "
                                 "reset(states) to return those states)")
        return full

    # ---- episodes ----------------------------------------------------------------------------
    def reset_all(self) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # avoid is evaluated: as in step
            return self.start(*self._sample(self.B))

    def start(self, states: np.ndarray, k) -> np.ndarray:
        """Start every entry at the given initial states ``[B, n]`` with episode lengths ``k``
        (an int or ``[B]``); returns the observations. Evaluation starts its seeded states here."""
        self.states = self._set_states(np.asarray(states, dtype=np.float64).reshape(self.B, self.n))
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # as in step
            for tr in self.trackers:
                tr.restart_all(self.states)
        self.t[:] = 0
        self.k[:] = k
        self.end[:] = 0
        self.t_reach[:] = np.where(self.asap.sat, 0, -1)
        self._keep_info(self.asap.rob, self.asap.sat)
        return self.obs()

    def restart(self, mask: np.ndarray, states: np.ndarray) -> np.ndarray:
        """Start the masked entries afresh at ``states [B, n]`` (their rows under ``mask``), each
        with the episode length it has; returns their observations ``[mask.sum(), ...]``. What an
        autoreset does, at states the caller chose (a training curriculum's starts)."""
        mask = np.asarray(mask, dtype=bool)
        cand = self.states.copy()
        cand[mask] = np.asarray(states, dtype=np.float64).reshape(self.B, self.n)[mask]
        self.states = self._set_states(cand, mask=mask)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # as in step
            for tr in self.trackers:
                tr.restart(mask, cand)
        self.t[mask] = 0
        self.t_reach[mask] = np.where(self.asap.sat[mask], 0, -1)
        return self.obs()[mask]

    def step(self, actions):
        """Advance every entry; returns (obs, reward, terminated, truncated, final_obs, done)."""
        # Huge states overflow in regions and rewards, and W209 operations give NaN: both are
        # handled below (non_finite), so numpy's warnings about them are not the user's business.
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return self._step(actions)

    def _step(self, actions):
        a = np.asarray(actions, dtype=np.float64).reshape(self.B, -1)
        if a.shape[1] != self.system.n_action:
            raise ValueError(f"actions must have shape [{self.B}, {self.system.n_action}]; got {np.shape(actions)}")
        new = self.sim.step(a)
        self.t += 1
        finite = np.isfinite(new).all(axis=1)
        safe = new if finite.all() else np.where(finite[:, None], new, self.states)
        oob = ((safe < self.low) | (safe > self.high)).any(axis=1)
        if self.avoid is not None:
            self.avoid.step(safe)
        end = np.zeros(self.B, dtype=np.int64)
        end[oob] = _OOB
        if self.avoid is not None:
            end[self.avoid.sat] = _AVOID
        end[~finite] = _NONFINITE
        failed = end > 0
        truncated = ~failed & (self.t >= self.k)
        end[truncated] = _TIME
        done = end > 0
        restart = self.autoreset and done.any()
        if restart:  # fresh episodes for the finished entries (drawn now; set after the info below)
            s0, k0 = self._sample(int(done.sum()))
            cand = np.zeros((self.B, self.n))
            cand[done] = s0
            kc = np.zeros(self.B, dtype=np.int64)
            kc[done] = k0
        for tr in self._late:
            if restart:  # step, then reset the finished entries and feed their initial states
                tr.step_and_restart(safe, done, cand)
            else:
                tr.step(safe)
        asap_rob, asap_sat = self.asap.step_rob, self.asap.step_sat  # at the reached states
        reward = self.reward.value(safe, asap_rob, asap_sat, failed)
        # A NaN robustness (an operation left its domain, lint's W209) or a reward that is not a
        # finite float32 (SB3 stores float32) ends the episode as non_finite, with a finite reward.
        bad = np.isnan(asap_rob) | ~(np.abs(reward) <= FLOAT32_MAX)
        if self.avoid is not None:
            bad |= np.isnan(self.avoid.step_rob)
        if bad.any():
            reward = np.where(bad, self.reward.non_finite_value, reward)
            asap_sat = asap_sat & ~bad
            late = bad & ~done  # finished only now: their fresh episodes are drawn here
            end[bad] = _NONFINITE
            failed |= bad
            truncated &= ~bad
            done |= bad
            if self.autoreset and late.any():
                s0, k0 = self._sample(int(late.sum()))
                if not restart:
                    cand, kc, restart = np.zeros((self.B, self.n)), np.zeros(self.B, dtype=np.int64), True
                cand[late], kc[late] = s0, k0
                for tr in self._late:
                    tr.restart(late, cand)
        newly = asap_sat & ~failed & (self.t_reach < 0)
        self.t_reach[newly] = self.t[newly]
        self.states = safe
        self.end = end
        obs = self.obs()
        self._keep_info(asap_rob, asap_sat)  # of the finished step (before any autoreset)
        final_obs = None
        if restart:
            final_obs = obs[done].copy()
            self.final_states = safe[done].copy()  # the true terminal states (obs are float32, clipped)
            # The finished entries' fresh episodes: asap and the reward trackers restarted above
            # (reset, then a masked monitor update with the initial states; the others do not advance).
            self.states = self._set_states(cand, mask=done)
            if self.avoid is not None:
                self.avoid.restart(done, cand)
            self.t[done] = 0
            self.k[done] = kc[done]
            self.t_reach[done] = np.where(self.asap.sat[done], 0, -1)
            obs = self.obs()
        return obs, reward, failed, truncated, final_obs, done


def core_of(venv) -> EnvCore:
    """The core stepping ``venv``: an :class:`AsapVecEnv`'s, under any stack of stable-baselines3
    ``VecEnvWrapper`` s (each holds the env it wraps as ``venv``)."""
    while not hasattr(venv, "core"):
        venv = venv.venv
    return venv.core


def infos(core: EnvCore) -> list[dict]:
    """One ``info`` dict per entry for the core's last reset or step (before any autoreset; the
    module docstring says what each key means). Any core with ``EnvCore``'s ``info_*`` arrays."""
    return list(map(_info, core.info_rho.tolist(), core.info_sat.tolist(), core.info_t_reach.tolist(),
                    core.info_end.tolist(), core.info_t.tolist()))


def with_terminal(out: list[dict], done: np.ndarray, term: np.ndarray, trunc: np.ndarray,
                  final_obs: np.ndarray) -> list[dict]:
    """SB3's autoreset contract on the infos of a step: each finished entry's info gets its
    ``terminal_observation`` (``final_obs``: one row per finished entry, in order) and
    ``TimeLimit.truncated`` (the episode hit its length, no failure)."""
    limit = (trunc & ~term).tolist()
    for i, row in zip(np.flatnonzero(done).tolist(), final_obs):
        out[i]["terminal_observation"] = row
        out[i]["TimeLimit.truncated"] = limit[i]
    return out


def _info(rho: float, satisfied: bool, t_reach: int, end: int, t: int) -> dict:
    return {"rho": rho, "satisfied": satisfied, "t_reach": None if t_reach < 0 else t_reach,
            "end_reason": END_REASONS[end], "t": t}


class AsapEnv(gym.Env):
    """One episode at a time (a batch of one); see the module docstring for the rules."""

    metadata = {"render_modes": ["rgb_array", "human"]}  # asap_dsl.render draws the frames

    def __init__(self, program, task: Optional[str] = None, reward: Any = None, seed: Optional[int] = None,
                 failure_reward: Optional[float] = None, render_mode: Optional[str] = None,
                 engine: Optional[str] = None):
        super().__init__()
        self.core = with_engine(EnvCore(program, task, 1, reward, autoreset=False, failure_reward=failure_reward),
                                engine)
        self.program, self.task = program, self.core.task
        self.observation_space = self.core.observation_space
        self.action_space = self.core.action_space
        self.render_mode = render_mode
        self._renderer = None
        if render_mode is not None:
            from .render import make_renderer

            self._renderer = make_renderer(program, self.task.name, render_mode)  # RenderError: why not
            self.metadata = {**self.metadata, "render_fps": self._renderer.fps}
        self._first_seed = seed
        self.spec_file = program.file

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        if seed is None and self._first_seed is not None:
            seed, self._first_seed = self._first_seed, None
        super().reset(seed=seed)
        self.core.rng = self.np_random
        obs = self.core.reset_all()
        if self.render_mode == "human":
            self.render()
        return obs[0], infos(self.core)[0]

    def step(self, action):
        obs, r, term, trunc, _, _ = self.core.step(np.asarray(action, dtype=np.float64)[None])
        if self.render_mode == "human":
            self.render()
        return obs[0], float(r[0]), bool(term[0]), bool(trunc[0]), infos(self.core)[0]

    def render(self):
        """The current state as an RGB array (``rgb_array``), or shown in a window (``human``);
        None without a render mode (gymnasium's contract)."""
        if self._renderer is None:
            return None
        state, t = self.core.states[0], int(self.core.t[0])
        if self.render_mode == "human":
            return self._renderer.show(state, t)
        return self._renderer.frame(state, t)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _vec_base():
    from stable_baselines3.common.vec_env import VecEnv

    return VecEnv


class AsapVecEnv(_vec_base()):
    """``num_envs`` entries stepped together in numpy; an SB3 ``VecEnv`` with autoreset."""

    def __init__(self, program, task: Optional[str] = None, num_envs: int = 1, seed: Optional[int] = None,
                 reward: Any = None, failure_reward: Optional[float] = None, engine: Optional[str] = None):
        self.core = with_engine(EnvCore(program, task, num_envs, reward, autoreset=True,
                                        failure_reward=failure_reward), engine)
        self.render_mode = None
        super().__init__(int(num_envs), self.core.observation_space, self.core.action_space)
        self.program, self.task = program, self.core.task
        self.core.rng = np.random.default_rng(seed)
        self._actions = None
        self._vec_step = getattr(self.core, "vec_step", None)

    # SB3 interface
    def reset(self):
        if self._seeds and self._seeds[0] is not None:
            self.core.rng = np.random.default_rng(self._seeds[0])
        self._reset_seeds()
        obs = self.core.reset_all()
        self.reset_infos = infos(self.core)
        return obs

    def step_async(self, actions) -> None:
        self._actions = actions

    def step_arrays(self, actions):
        """(obs, reward, terminated, truncated) as arrays, autoreset done; no info dicts."""
        obs, r, term, trunc, final_obs, done = self.core.step(actions)
        self.last_final_obs, self.last_done = final_obs, done
        return obs, r.astype(np.float32), term, trunc

    def step_wait(self):
        if self._vec_step is not None:  # the compiled core's own, without per-entry arrays (asap_dsl.native)
            return self._vec_step(self._actions)
        obs, r, term, trunc = self.step_arrays(self._actions)
        out = infos(self.core)
        done = self.last_done
        if done.any():
            with_terminal(out, done, term, trunc, self.last_final_obs)
        return obs, r, done.copy(), out

    def close(self) -> None:
        pass

    def get_attr(self, attr_name, indices=None):
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name, value, indices=None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        return [getattr(self, method_name)(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False for _ in self._get_indices(indices)]

    def _get_indices(self, indices):
        if indices is None:
            return range(self.num_envs)
        if isinstance(indices, int):
            return [indices]
        return indices


def make_env(prog_or_path, task: Optional[str] = None, reward: Any = None, seed: Optional[int] = None, **kw) -> AsapEnv:
    """A ``gymnasium.Env`` for one task of a spec: one episode at a time, with the rules of the
    module docstring.

    :param prog_or_path: a :class:`asap_dsl.Program`, or the path of a ``.asap`` file (loaded
        with :func:`asap_dsl.load`; a broken spec raises :class:`asap_dsl.SpecError`)
    :param task: the task's name; None for a spec with one task (KeyError, with the closest
        name, for an unknown one)
    :param reward: None for the task's own reward, or ``"asap"``, ``"rho"``,
        ``"rho(window = 5)"``, ``"distance(lambda_t = 1, lambda_o = 1, base = 0)"`` (as the
        ``reward`` clause writes it; ValueError, one sentence, for a bad one)
    :param seed: seeds the first ``reset`` (later resets continue its random stream)
    :param kw: ``failure_reward``, a constant for the failure step instead of the reward's
        floor; ``render_mode``, ``"rgb_array"`` or ``"human"`` (:mod:`asap_dsl.render`: MuJoCo's
        offscreen renderer for the swimmer, a state-space frame otherwise); ``engine``, what steps the
        episodes: ``"native"`` (compiled, :mod:`asap_dsl.native`), ``"numpy"`` or ``"auto"``
        (compiled where that covers the task; None: ``$ASAP_ENGINE``, else auto)
    :return: the environment (observations float32, actions clipped to the action bounds)
    """
    return AsapEnv(_program(prog_or_path), task=task, reward=reward, seed=seed, **kw)


def make_vec_env(prog_or_path, task: Optional[str] = None, num_envs: int = 1, seed: Optional[int] = None,
                 reward: Any = None, **kw) -> AsapVecEnv:
    """A stable-baselines3 ``VecEnv`` of ``num_envs`` episodes of one task, stepped together in
    numpy; a finished entry restarts at once (its info holds ``terminal_observation`` and
    ``TimeLimit.truncated``).

    :param prog_or_path: a :class:`asap_dsl.Program`, or the path of a ``.asap`` file
    :param task: the task's name; None for a spec with one task
    :param num_envs: the number of entries, a whole number of at least 1
    :param seed: seeds the initial states and episode lengths of every entry (None: fresh entropy)
    :param reward: None for the task's own reward, or a reward as :func:`make_env` takes it
    :param kw: ``failure_reward``, a constant for the failure step instead of the reward's floor;
        ``engine``, as :func:`make_env` takes it (the compiled step is one call per vector step)
    :return: the vector environment
    """
    return AsapVecEnv(_program(prog_or_path), task=task, num_envs=num_envs, seed=seed, reward=reward, **kw)


# ---- gymnasium ids ----------------------------------------------------------------------------

# The ids and their registration: asap_dsl.registration (`import asap_dsl` registers them).
SPECS_DIR = specs_dir()


def _make_registered(path: str, task: str, **kw):
    return make_env(path, task=task, **kw)


def register_envs(directory: Union[str, os.PathLike, None] = None) -> list[str]:
    """Register ``asap/<spec>-<task>-v0`` for each task of each ``*.asap`` in ``directory``
    (default: the benchmark specs), each spec loaded and checked now: a broken one is left out.
    :func:`asap_dsl.register` does one spec."""
    from .diagnostics import SpecError
    from .registration import register

    d = Path(directory) if directory is not None else SPECS_DIR
    ids: list[str] = []
    for f in sorted(d.glob("*.asap")) if d.is_dir() else ():
        try:
            ids += register(f)
        except (SpecError, OSError):  # a broken spec is not registered; lint reports it
            continue
    return ids


REGISTERED_IDS = register_benchmarks()  # what `import asap_dsl` registers: the ids, without parsing the specs
