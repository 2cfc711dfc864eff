"""The compiled core: the numpy core's episodes with the step compiled (see :mod:`asap_dsl.native`).

:class:`NativeCore` takes a built numpy core (:class:`asap_dsl.env.EnvCore`: its task, reward,
spaces, simulator and random generator, everything that is not per step) and replaces ``start``
and ``step``: one call into the generated module per vector step, every per-entry value kept in
two preallocated arrays. Fresh episodes are drawn from the core's own generator in the numpy
core's order, so both cores given the same seed and actions go through the same episodes.
"""

from __future__ import annotations

import logging
from typing import Any, Optional

import numpy as np

from ..env import _info, with_terminal
from ..sampling import init_box
from . import draws
from .cache import Loaded, load
from .episode import RewardSpec, StepSpec
from .exprs import NotCovered
from .kernel import Kernel, generate

log = logging.getLogger("asap_dsl.native")

_F32, _F64 = np.dtype(np.float32), np.dtype(np.float64)

#: A generated module of more lines than this would take minutes to compile (numba's time
#: grows with a function's size): such a spec (thousands of terms or lets) steps in numpy.
MAX_LINES = 6_000


def step_spec(core) -> StepSpec:
    """What the compiled step computes with, read off a numpy core."""
    rw = core.reward
    common = dict(floor=rw.floor, non_finite=float(rw.non_finite_value))
    if rw.kind == "asap":
        reward = RewardSpec("asap", bounds=tuple(rw.bounds), scale=float(rw.scale), r_sat=float(rw.r_sat), **common)
    elif rw.kind == "rho":
        reward = RewardSpec("rho", bounds=tuple(rw.bounds), node=rw.node, **common)
    else:
        reward = RewardSpec("distance", goals=tuple(rw.goal), obstacles=tuple(rw.obstacles), lambda_t=float(rw.lt),
                            lambda_o=float(rw.lo_), base=float(rw.base), **common)
    low, high = init_box(core.system, core.tm.init_box)
    return StepSpec(
        system=core.system, regions=dict(core.program.regions), asap=core.asap.node,
        avoid=core.avoid.node if core.avoid is not None else None, reward=reward,
        clip_lo=tuple(map(float, core._clip_lo)), clip_hi=tuple(map(float, core._clip_hi)),
        obs_low=tuple(map(float, core.obs_low)), obs_high=tuple(map(float, core.obs_high)),
        observe_time=bool(core.observe_time), deadline=int(core.tm.deadline),
        rho_info=(float(core._rho_lo), float(core._rho_hi)), init_low=tuple(map(float, low)),
        init_high=tuple(map(float, high)), episode=(int(core.kmin), int(core.kmax)))


def _signatures(kernel: Kernel):
    from numba import types as nt

    f64, i64, f32 = nt.float64[:, ::1], nt.int64[:, ::1], nt.float32[:, ::1]
    rest = (f64, i64, f32, nt.float32[::1], nt.boolean[:, ::1])
    sigs = {"restart": [(nt.boolean[::1], f64, i64, f32)]}
    if kernel.black_box:
        sigs["post"] = [(f64,) + rest]
    else:  # float32 actions (SB3's); float64 ones compile on first use (and are cached too)
        sigs["step"] = [(f32,) + rest]
    return sigs


def compile_kernel(kernel: Kernel) -> Loaded:
    """The compiled module of ``kernel`` (its machine code from the cache when it is there)."""
    sigs = _signatures(kernel)

    def build(module):
        for name, ss in sigs.items():
            for s in ss:
                getattr(module, name).compile(s)

    return load(kernel.source, build)


class _Live:
    """asap's ``rob``/``sat`` at each entry's newest step (views into the core's rows).

    ``step_rob``/``step_sat`` are the numpy trackers' names for the values at the step just
    taken: the same as the live ones where no entry restarted since (``autoreset=False``, the
    offline :class:`asap_dsl.rollout.Evaluator`'s core)."""

    def __init__(self, rob: np.ndarray, sat: np.ndarray):
        self.rob, self.sat = rob, sat

    @property
    def step_rob(self) -> np.ndarray:
        return self.rob

    @property
    def step_sat(self) -> np.ndarray:
        return self.sat > 0


class NativeCore:
    """The numpy core ``inner`` with ``start``/``step`` compiled: the same attributes and results.

    ``states``, ``t``, ``k``, ``t_reach``, ``end`` and the ``info_*`` arrays are views into the
    rows the compiled code writes (assigning into them, ``core.k[:] = 100``, changes the episodes).
    """

    engine = "native"

    def __init__(self, inner, kernel: Kernel, loaded: Loaded):
        self.inner, self.kernel, self.loaded = inner, kernel, loaded
        for name in ("program", "task", "tm", "system", "reward", "kmin", "kmax", "low", "high", "observe_time",
                     "obs_low", "obs_high", "observation_space", "action_space", "autoreset", "sim", "B", "n"):
            setattr(self, name, getattr(inner, name))
        B, n, c = self.B, self.n, kernel.cols
        self.m, self.cols = self.system.n_action, c
        self.compile_seconds, self.compiled_from_cache = loaded.seconds, loaded.from_cache
        mod = loaded.module
        self._step, self._post, self._restart = getattr(mod, "step", None), getattr(mod, "post", None), mod.restart
        self._black_box = kernel.black_box
        self.F = np.zeros((B + 1, kernel.nf))  # row B: scratch
        self.I = np.zeros((B + 1, kernel.ni), dtype=np.int64)
        self.I[:B, c.t_reach] = -1
        self.I[B, c.autoreset] = int(bool(self.autoreset) and not self._black_box)
        rows, irows = self.F[:B], self.I[:B]
        self.states = rows[:, :n]
        self.t, self.k, self.t_reach, self.end = (irows[:, j] for j in (c.t, c.k, c.t_reach, c.end))
        self.asap = _Live(rows[:, c.arob], irows[:, c.asat])
        self.info_t_reach, self.info_end, self.info_t = (irows[:, j] for j in (c.info_t_reach, c.info_end, c.info_t))
        self._rew = rows[:, c.rew]
        self.info_rho = rows[:, c.rho]
        self.info_sat = np.zeros(B, dtype=bool)
        self._obs_shape, self._act_shape = (B, c.n_obs), (B, self.m)
        self._all = np.ones(B, dtype=bool)
        self._finished = 0
        self.rng = inner.rng  # the generator's addresses into row B
        if inner.avoid is not None:  # fresh episodes of start() too are checked compiled
            inner.avoid_at_start = self.avoid_at_start

    # ---- what the numpy core has ---------------------------------------------------------------
    @property
    def rng(self) -> np.random.Generator:
        return self.inner.rng

    @rng.setter
    def rng(self, value: np.random.Generator) -> None:
        self.inner.rng = value
        c = self.cols
        self.I[self.B, [c.rs, c.rd, c.ru]] = draws.pointers(value)

    @property
    def final_states(self) -> Optional[np.ndarray]:
        """The true states that ended the episodes of the last autoreset (one row per entry)."""
        if not self._finished:
            return None
        return self.F[:self._finished, self.cols.final: self.cols.final + self.n].copy()

    def _finite_rho(self, rho: np.ndarray) -> np.ndarray:
        return self.inner._finite_rho(rho)

    def obs(self, states=None, t=None, k=None) -> np.ndarray:
        """Observations of ``states`` (default: the current ones), as the numpy core makes them."""
        return self.inner.obs(self.states if states is None else states, self.t if t is None else t,
                              self.k if k is None else k)

    def avoid_at_start(self, states: np.ndarray) -> np.ndarray:
        """Where ``avoid`` holds at step 0 of traces starting at ``states [m, n]`` (what the
        offline evaluator gives), from the compiled monitors on scratch rows."""
        m, c = states.shape[0], self.cols
        F = np.zeros((m + 1, self.kernel.nf))
        I = np.zeros((m + 1, self.kernel.ni), dtype=np.int64)
        F[:m, c.cand: c.cand + self.n] = states
        self._restart(np.ones(m, dtype=bool), F, I, np.empty((m, c.n_obs), dtype=np.float32))
        return I[:m, c.vsat] > 0

    def _start(self, states: np.ndarray, k: np.ndarray, mask: np.ndarray, obs: np.ndarray) -> None:
        """The masked entries started at ``states`` with episode lengths ``k`` (compiled)."""
        c = self.cols
        self.F[:self.B, c.cand: c.cand + self.n][mask] = states[mask]
        self.I[:self.B, c.kc][mask] = k[mask]
        self._restart(mask, self.F, self.I, obs)

    # ---- episodes ------------------------------------------------------------------------------
    def reset_all(self) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return self.start(*self.inner._sample(self.B))

    def start(self, states: np.ndarray, k) -> np.ndarray:
        """Start every entry at ``states [B, n]`` with episode lengths ``k`` (int or ``[B]``);
        returns the observations."""
        s = np.asarray(states, dtype=np.float64).reshape(self.B, self.n)
        if self._black_box:
            s = self._set_sim(s, None)
        obs = np.empty(self._obs_shape, dtype=np.float32)
        self._start(s, np.broadcast_to(np.asarray(k, dtype=np.int64), (self.B,)), self._all, obs)
        self.end[:] = 0
        self.info_rho[:] = self._finite_rho(self.asap.rob)
        self.info_sat = self.asap.sat > 0
        self.info_t_reach[:], self.info_end[:], self.info_t[:] = self.t_reach, 0, 0
        return obs

    def restart(self, mask: np.ndarray, states: np.ndarray) -> np.ndarray:
        """The numpy core's :meth:`~asap_dsl.env.EnvCore.restart`, compiled: the masked entries
        started at ``states [B, n]`` with the episode lengths they have; their observations."""
        mask = np.asarray(mask, dtype=bool)
        s = np.array(self.states)
        s[mask] = np.asarray(states, dtype=np.float64).reshape(self.B, self.n)[mask]
        if self._black_box:
            s = self._set_sim(s, mask)
        obs = np.empty(self._obs_shape, dtype=np.float32)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            self._start(s, np.array(self.k), mask, obs)
        return obs[mask]

    def _set_sim(self, states: np.ndarray, mask: Optional[np.ndarray]) -> np.ndarray:
        """A black-box simulator set to ``states`` (the masked entries), checked by the numpy core."""
        self.inner.states = self.states.copy()
        return self.inner._set_states(states, mask=mask)

    def _actions(self, actions: Any) -> np.ndarray:
        a = np.asarray(actions, dtype=np.float64).reshape(self.B, -1)
        if a.shape[1] != self.m:
            raise ValueError(f"actions must have shape [{self.B}, {self.m}]; got {np.shape(actions)}")
        return np.ascontiguousarray(a)

    def _advance(self, actions):
        """One compiled step: (obs, float32 rewards, flags, final_obs or None)."""
        a = actions
        # Anything but a float32/float64 array of the right shape is converted (another memory
        # layout compiles once more, on first use).
        if type(a) is not np.ndarray or (a.dtype is not _F32 and a.dtype is not _F64) or a.shape != self._act_shape:
            a = self._actions(actions)
        obs = np.empty(self._obs_shape, dtype=np.float32)
        rew = np.empty(self.B, dtype=np.float32)
        flags = np.empty((5, self.B), dtype=bool)
        if self._black_box:
            new = np.ascontiguousarray(self.sim.step(a), dtype=np.float64)
            ndone = self._post(new, self.F, self.I, obs, rew, flags)
        else:
            ndone = self._step(a, self.F, self.I, obs, rew, flags)
        final_obs = None
        if ndone:
            if ndone < 0:
                from ..sampling import INIT_BOX_IN_AVOID

                raise ValueError(INIT_BOX_IN_AVOID)
            if self.autoreset:
                c = self.cols
                final_obs = self.F[:ndone, c.final_obs: c.final_obs + c.n_obs].astype(np.float32)
                self._finished = ndone
                if self._black_box:
                    self._autoreset(flags[2], flags[3], obs)
        return obs, rew, flags, final_obs

    def step(self, actions):
        """Advance every entry; returns (obs, reward, terminated, truncated, final_obs, done)."""
        obs, _, flags, final_obs = self._advance(actions)
        self.info_sat = flags[4]
        return obs, self._rew.copy(), flags[0], flags[1], final_obs, flags[2]

    def vec_step(self, actions):
        """SB3's ``step_wait``: (obs, float32 rewards, dones, infos), the infos of finished entries
        with ``terminal_observation`` and ``TimeLimit.truncated`` (:func:`asap_dsl.env.with_terminal`)."""
        obs, rew, flags, final_obs = self._advance(actions)
        c, F, I = self.cols, self.F, self.I
        self.info_sat = flags[4]
        if self.B == 1:  # one dict from the rows' items: no arrays made for it
            out = [_info(F.item(0, c.rho), flags.item(4, 0), I.item(0, c.info_t_reach), I.item(0, c.info_end),
                         I.item(0, c.info_t))]
        else:
            out = list(map(_info, self.info_rho.tolist(), flags[4].tolist(), self.info_t_reach.tolist(),
                           self.info_end.tolist(), self.info_t.tolist()))
        done = flags[2]
        if final_obs is not None:
            with_terminal(out, done, flags[0], flags[1], final_obs)
        return obs, rew, done, out

    def _autoreset(self, done: np.ndarray, late: np.ndarray, obs: np.ndarray) -> None:
        """A black-box simulator's finished entries started afresh (the compiled step draws and
        starts them itself): drawn first those the end reasons ended, then those a non-finite
        value ended (the numpy core's order), the simulator reset, the entries started."""
        cand = np.zeros((self.B, self.n))
        kc = np.zeros(self.B, dtype=np.int64)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            for mask in (done & ~late, late):
                if mask.any():
                    cand[mask], kc[mask] = self.inner._sample(int(mask.sum()))
        self._start(self._set_sim(cand, done), kc, done, obs)


def native_core(inner, require: bool = False):
    """``inner`` (a numpy core) with its step compiled, or ``inner`` itself where the compiled
    step does not cover it (the reason is logged; with ``require`` it is raised as ValueError)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        reason = "numba is not installed"
    else:
        try:
            kernel = generate(step_spec(inner))
            lines = kernel.source.count("\n")
            if lines > MAX_LINES:
                raise NotCovered(f"its step is {lines:,} lines of code, more than the {MAX_LINES:,} compiled in "
                                 "reasonable time")
            loaded = compile_kernel(kernel)
            core = NativeCore(inner, kernel, loaded)
            log.info("compiled step of %s task %s: %.2f s (%s) at %s", inner.program.file, inner.task.name,
                     loaded.seconds, "machine code from the cache" if loaded.from_cache else "compiled", loaded.path)
            return core
        except NotCovered as err:
            reason = str(err)
        except Exception as err:  # noqa: BLE001 - a failure of the generator or of numba: a bug
            if require:
                raise
            log.warning("the compiled step of %s task %s could not be built (numpy steps it instead): %s: %s",
                        inner.program.file, inner.task.name, type(err).__name__, str(err).splitlines()[0])
            return inner
    if require:
        raise ValueError(f"the compiled step does not cover task {inner.task.name}: {reason}")
    log.info("numpy step for %s task %s: %s", inner.program.file, inner.task.name, reason)
    return inner


__all__ = ["MAX_LINES", "NativeCore", "compile_kernel", "native_core", "step_spec"]
