"""What one entry's step computes after its dynamics, as source lines: the numpy core's rules.

:class:`StepSpec` holds what :class:`asap_dsl.env.EnvCore` computes with (read off it by
:func:`asap_dsl.native.core.step_spec`); the functions here write, for entry ``b`` of the rows
``F``/``I`` (columns in :class:`Cols`), what ``EnvCore.step`` does, in its order: a non-finite
state replaced by the last one, leaving the state space, the monitors (``_observe``), the end
reasons (non_finite over avoid over out_of_bounds, then time_limit), the reward
(:class:`asap_dsl.rewards.Reward`), the non-finite checks (a NaN robustness, a reward beyond
float32), the first step at which ``asap`` held, the observation (``EnvCore.obs``) and the info.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

from ..model import RegionModel, SystemModel
from ..stl import ir
from .exprs import Body, mn, mx, number, region_distance

_F32MAX = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class RewardSpec:
    """The reward of a task as numbers (read off :class:`asap_dsl.rewards.Reward`)."""

    kind: str                                              # asap | rho | distance
    bounds: tuple[float, float] = (-math.inf, math.inf)   # rho is clipped into these (asap, rho)
    scale: float = 1.0                                     # asap
    r_sat: float = 0.0                                     # asap
    floor: Optional[float] = None                          # the failure step's reward
    non_finite: float = 0.0                                # the reward of a non-finite step
    node: Optional[ir.Formula] = None                      # rho: the tracked formula
    goals: tuple[RegionModel, ...] = ()                    # distance
    obstacles: tuple[RegionModel, ...] = ()
    lambda_t: float = 1.0
    lambda_o: float = 1.0
    base: float = 0.0


@dataclass(frozen=True)
class StepSpec:
    """Everything the step of one task computes with, as the numpy core holds it."""

    system: SystemModel
    regions: Mapping[str, RegionModel]
    asap: ir.Formula
    avoid: Optional[ir.Formula]
    reward: RewardSpec
    clip_lo: tuple[float, ...]      # the state is clipped into these (float64) before float32
    clip_hi: tuple[float, ...]
    obs_low: tuple[float, ...]      # float32 values; with observe time one more
    obs_high: tuple[float, ...]
    observe_time: bool
    deadline: int
    rho_info: tuple[float, float]   # info's rho for -inf and +inf
    init_low: tuple[float, ...]     # the initial box (the task's own or the system's)
    init_high: tuple[float, ...]
    episode: tuple[int, int]        # kmin, kmax


@dataclass
class Cols:
    """Columns of each entry's float row ``F[b]`` and int row ``I[b]`` besides the monitors'."""

    n: int
    n_obs: int
    arob: int = 0       # F: asap's live robustness (after a restart: of the initial state)
    rew: int = 0        # F: the last step's reward and info rho
    rho: int = 0
    final: int = 0      # F: the states that ended episodes and their observations, in rows 0, 1, ...
    final_obs: int = 0  # (the finished entries in order; rewritten each step)
    cand: int = 0       # F: the fresh episode's initial state
    t: int = 0          # I: step, episode length, t_reach (-1: not yet), end code
    k: int = 0
    t_reach: int = 0
    end: int = 0
    asat: int = 0       # I: asap and avoid hold now (live values)
    vsat: int = 0
    info_t_reach: int = 0  # I: the last step's info (before any autoreset)
    info_end: int = 0
    info_t: int = 0
    kc: int = 0         # I: the fresh episode's length; scratch for the redraws
    bad: int = 0
    autoreset: int = 0  # I, in the extra row B: restart finished entries, the generator's addresses
    rs: int = 0
    rd: int = 0
    ru: int = 0


def _clip_finite(x: str, bounds: tuple[float, float]) -> list[str]:
    """``rewards._clip_finite``: np.clip into the bounds, then ±inf (and NaN) as 0 where a bound is infinite."""
    lo, hi = bounds
    lines = [f"q = {mx(x, number(lo))}", f"q = {mn('q', number(hi))}"]
    if not (math.isfinite(lo) and math.isfinite(hi)):
        lines.append("q = q if math.isfinite(q) else 0.0")
    return lines


def reward_lines(rw: RewardSpec) -> list[str]:
    """Lines computing ``r`` from ``ar`` (asap's ρ), ``sat``, ``q`` (the reward's own value: its
    tracker's ρ, or the distance term) and ``failed``."""
    if rw.kind == "asap":
        lines = _clip_finite("ar", rw.bounds) + [f"rho = q * {number(rw.scale)}", f"r = {number(rw.r_sat)} if sat else rho"]
        return lines + ["if failed:", f"    r = {'rho' if rw.floor is None else number(rw.floor)}"]
    lines = (_clip_finite("q", rw.bounds) if rw.kind == "rho" else []) + ["r = q"]
    if rw.floor is not None:
        lines += ["if failed:", f"    r = {number(rw.floor)}"]
    return lines


def distance_term(body: Body, rw: RewardSpec) -> str:
    """``-lambda_t d_T + lambda_o d_O + base``, the distances' minima over the regions (NaN wins)."""
    d_t = None
    for g in rw.goals:
        d = region_distance(body, g)
        d_t = d if d_t is None else body.temp(mn(d_t, d))
    d_o = None
    for o in rw.obstacles:
        d = region_distance(body, o)
        d_o = d if d_o is None else body.temp(mn(d_o, d))
    return body.temp(f"({number(-rw.lambda_t)} * {d_t} + {number(rw.lambda_o)} * {d_o or '0.0'}) + {number(rw.base)}")


def obs_lines(spec: StepSpec, X: str, t: str, k: str, dst: str) -> list[str]:
    """Lines writing the observation of state ``X`` at step ``t`` of ``k`` into ``dst.format(i=...)``:
    clipped into the state space, float32, clipped again in float32; with ``observe time`` the
    steps left over the deadline."""
    n = spec.system.n_state
    out = []
    for i in range(n):
        out += [f"o = {mx(f'{X}[{i}]', number(spec.clip_lo[i]))}", f"o = {mn('o', number(spec.clip_hi[i]))}",
                "o = np.float32(o)", f"o = {mx('o', number(spec.obs_low[i]))}", f"o = {mn('o', number(spec.obs_high[i]))}",
                f"{dst.format(i=i)} = o"]
    if spec.observe_time:
        out += [f"o = ({k} - {t}) / {spec.deadline}", f"o = {mx('o', '0.0')}", f"o = {mn('o', number(spec.obs_high[n]))}",
                f"{dst.format(i=n)} = np.float32(o)"]
    return out


def finish_lines(spec: StepSpec, c: Cols) -> list[str]:
    """Lines finishing entry ``b``'s step from ``S`` (its state) and ``N`` (the state reached):
    everything but the autoreset; ``ndone`` counts the finished entries."""
    sysm = spec.system
    n = sysm.n_state
    finite = " and ".join(f"math.isfinite(N[{i}])" for i in range(n))
    oob = " or ".join(f"X[{i}] < {number(sysm.state_low[i])} or X[{i}] > {number(sysm.state_high[i])}"
                      for i in range(n))
    rlo, rhi = spec.rho_info
    avoid = spec.avoid is not None
    L = [f"t = I[b, {c.t}] + 1",
         f"I[b, {c.t}] = t",
         f"finite = {finite}",
         "X = N if finite else S",
         f"oob = {oob}",
         "ar, asat, vr, vsat, q = _observe(X, t, F, I, b)",
         "end = 2 if oob else 0"]
    if avoid:
        L += ["if vsat > 0.0:", "    end = 1"]
    L += ["if not finite:", "    end = 3",
          "failed = end > 0",
          f"trunc = (not failed) and t >= I[b, {c.k}]",
          "if trunc:", "    end = 4",
          "done = end > 0",
          "sat = asat > 0.0"]
    L += reward_lines(spec.reward)
    bad = f"ar != ar or not (abs(r) <= {number(_F32MAX)})" + (" or vr != vr" if avoid else "")
    L += ["late = False",
          f"if {bad}:",
          f"    r = {number(spec.reward.non_finite)}",
          "    sat = False",
          "    late = not done",
          "    end = 3", "    failed = True", "    trunc = False", "    done = True",
          f"tr = I[b, {c.t_reach}]",
          "if sat and not failed and tr < 0:",
          "    tr = t",
          f"    I[b, {c.t_reach}] = tr"]
    L += [f"F[b, {i}] = X[{i}]" for i in range(n)]
    L += [f"F[b, {c.arob}] = ar",
          f"I[b, {c.asat}] = 1 if sat else 0",
          f"I[b, {c.vsat}] = 1 if vsat > 0.0 else 0",
          f"I[b, {c.end}] = end"]
    L += obs_lines(spec, "X", "t", f"I[b, {c.k}]", "obs[b, {i}]")
    L += [f"F[b, {c.rew}] = r",
          "rew32[b] = r",
          # np.nan_to_num: NaN as 0, ±inf (an empty past window) as the formula's bounds
          f"F[b, {c.rho}] = 0.0 if ar != ar else ({number(rhi)} if ar == _INF else "
          f"({number(rlo)} if ar == -_INF else ar))",
          f"I[b, {c.info_t_reach}] = tr", f"I[b, {c.info_end}] = end", f"I[b, {c.info_t}] = t",
          "flags[0, b] = failed", "flags[1, b] = trunc", "flags[2, b] = done", "flags[3, b] = late",
          "flags[4, b] = sat",
          "if done:"]  # the terminal state and observation, packed: the j-th finished entry's in row j
    L += [f"    F[ndone, {c.final + i}] = X[{i}]" for i in range(n)]
    L += [f"    F[ndone, {c.final_obs + i}] = obs[b, {i}]" for i in range(c.n_obs)]
    return L + ["    ndone += 1"]


def start_lines(spec: StepSpec, c: Cols, X: str, k: str) -> list[str]:
    """Lines starting entry ``b`` at state ``X`` with episode length ``k`` (step 0)."""
    n = spec.system.n_state
    return [f"X = {X}",
            "ar, asat, vr, vsat, q = _observe(X, zero, F, I, b)",
            *[f"F[b, {i}] = X[{i}]" for i in range(n)],
            f"F[b, {c.arob}] = ar",
            f"I[b, {c.t}] = 0",
            f"I[b, {c.k}] = {k}",
            f"I[b, {c.asat}] = 1 if asat > 0.0 else 0",
            f"I[b, {c.vsat}] = 1 if vsat > 0.0 else 0",
            f"I[b, {c.t_reach}] = 0 if asat > 0.0 else -1",
            *obs_lines(spec, "X", "0", k, "obs[b, {i}]")]
