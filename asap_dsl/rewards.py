"""Per-step rewards of a task, computed incrementally with online monitors.

Every reward is a function of the trace up to the state the step reached (step t = 1, 2, ...;
step 0 is the initial state and earns no reward). Nothing re-evaluates the prefix:

* ``asap`` — ASAP-Phi (the paper's equation 1): ``rho(s, t, phi_T)`` while ``phi_T`` does not hold at
  t, ``r_sat`` once it holds. With ``r_sat auto`` (the default) rho is clipped into the interval
  bounds ``[rho_min, rho_max]`` of ``phi_T`` over the state space and scaled by
  ``1 / (rho_max - rho_min)``; ``r_sat = rho_max' + k_max + 1``, which satisfies the theorem's
  ``r_sat > rho_max' + (rho_max' - rho_min') k_max``. A numeric ``r_sat`` is used as written and rho
  is left unscaled (still clipped into the bounds).
* ``rho`` — the robustness of the task's specification
  ``eventually[0, D] asap and always[0, D] not avoid`` at time 0 of the prefix (PrefixMonitor).
* ``rho(window = W)`` — the specification over the last W steps only (the paper's "finite dense"
  reward): the causal ``once[0, W-1] asap and historically[0, W-1] not avoid`` at t.
* ``distance(lambda_t, lambda_o, base)`` — ``-lambda_t d_T + lambda_o d_O + base`` with ``d_T`` (``d_O``) the
  Euclidean distance to the nearest region named by an ``in R`` atom of ``asap`` (``avoid``);
  without ``avoid`` the ``d_O`` term is 0.

**The failure step** (the step that ends the episode by ``avoid``, leaving the state space or a
non-finite state): the paper only stops the episode. Here that step earns the *floor* of the
reward: the lowest value the reward can take while ``phi_T`` does not hold — ``rho_min'`` (scaled)
for ``asap``, the lower interval bound of the formula for ``rho`` and ``rho(window)``. So a failure
never earns ``r_sat`` (in attitude control the unsafe ball lies inside the target) and can never
pay more than any other step. ``distance`` has no bound: it is evaluated on the reached state
(the last finite one), where ``d_O = 0`` inside an obstacle. ``failure_reward=`` overrides this with
a constant.

Values: rho of a past window that is still empty is +-inf by the semantics; rewards clip it into
the interval bounds, and where a bound is unknown (infinite) an infinite value becomes 0.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping, Optional

import numpy as np

from .model import RegionModel, RewardModel, TaskModel, formula_bounds
from .stl import ir

__all__ = ["FormulaTracker", "Reward", "check_reward_fits", "is_static", "make_reward", "parse_reward",
           "resolve_reward", "reward_trace", "static_eval"]


# --------------------------------------------------------------------------------------------
# Formula values at the newest step, batched, with per-entry restarts.
# --------------------------------------------------------------------------------------------


def is_static(node: ir.Formula) -> bool:
    """True for Boolean combinations of atoms (and ``true``/``false``): the value at t depends on
    the state s_t only, so :func:`static_eval` computes it without a monitor."""
    if isinstance(node, (ir.Atom, ir.Const)):
        return True
    if isinstance(node, (ir.Not, ir.And, ir.Or, ir.Implies)):
        return all(is_static(c) for c in ir.children(node))
    return False


def static_eval(node: ir.Formula, states: np.ndarray, boolean: bool) -> np.ndarray:
    """A static formula (:func:`is_static`) on the states ``[B, n]``: its satisfaction (bool
    ``[B]``) if ``boolean``, else its robustness (float64 ``[B]``; ``true``/``false`` are ±inf)."""
    if isinstance(node, ir.Atom):
        return np.asarray(node.satisfied(states) if boolean else node.robustness(states),
                          dtype=bool if boolean else np.float64)
    if isinstance(node, ir.Const):
        v = node.value if boolean else (math.inf if node.value else -math.inf)
        return np.full(states.shape[0], v, dtype=bool if boolean else np.float64)
    if isinstance(node, ir.Not):
        v = static_eval(node.arg, states, boolean)
        return ~v if boolean else -v
    a = static_eval(node.left, states, boolean)
    b = static_eval(node.right, states, boolean)
    if isinstance(node, ir.Implies):
        a = ~a if boolean else -a
    if isinstance(node, ir.And):
        return (a & b) if boolean else np.minimum(a, b)
    return (a | b) if boolean else np.maximum(a, b)


class FormulaTracker:
    """ρ (and ⊨) of a formula at the newest step of B traces, restartable per entry.

    ``restart_all(states)`` starts every trace at ``states`` (step 0); ``step(states)`` appends
    ``states``; ``restart(mask, cand)`` restarts the masked entries at the initial states
    ``cand [B, n]`` (only the masked rows are read; without ``cand``, the candidates given to the
    last ``step`` are used). Results are in ``.rob`` / ``.sat`` (``[B]``).
    ``step_and_restart(states, done, cand)`` is ``step(states)`` then ``restart(done, cand)`` with
    every atom evaluated once (on the reached and the restart states together). ``.step_rob`` /
    ``.step_sat`` hold the values at the states of the last ``step`` (before any restart), which
    is what a reward of that step reads.

    Formulas of atoms only are evaluated directly. Others use one online monitor of B entries:
    a restart is ``reset(mask)`` and ``update(cand, mask=mask)``, which advances the restarted
    entries only (to their step 0) and leaves the others as they are.
    """

    def __init__(self, node: ir.Formula, batch: int, n_state: int, *, satisfaction: bool = True):
        from .stl import online

        self.node, self.B, self.n = node, int(batch), n_state
        self.satisfaction = satisfaction
        self.static = is_static(node)
        self.rob = np.zeros(self.B)
        self.sat = np.zeros(self.B, dtype=bool)
        self.step_rob, self.step_sat = self.rob, self.sat
        self._cand = None
        if self.static:
            return
        self.mon = online.monitor_for(node, self.B, satisfaction=satisfaction, n_state=n_state)

    def _eval_static(self, states):
        rob = static_eval(self.node, states, False)
        sat = static_eval(self.node, states, True) if self.satisfaction else np.zeros(len(states), bool)
        return rob, sat

    def _update(self, states, mask=None):
        # The monitor returns new arrays on every update (never changed in place): no copies.
        self.rob = self.mon.update(states, mask=mask)
        if self.satisfaction:
            self.sat = self.mon.satisfied

    def restart_all(self, states: np.ndarray) -> None:
        states = np.asarray(states, dtype=np.float64)
        if self.static:
            self.rob, self.sat = self._eval_static(states)
            return
        self.mon.reset()
        self._update(states)
        self.step_rob, self.step_sat = self.rob, self.sat

    def step(self, states: np.ndarray, cand: Optional[np.ndarray] = None) -> None:
        states = np.asarray(states, dtype=np.float64)
        self._cand = cand
        if self.static:
            self.rob, self.sat = self._eval_static(states)
        else:
            self._update(states)
        self.step_rob, self.step_sat = self.rob, self.sat

    def step_and_restart(self, states: np.ndarray, done: np.ndarray, cand: np.ndarray) -> None:
        """``step(states)`` then ``restart(done, cand)``, evaluating every atom once on the reached
        states and the restart states (the ``done`` rows of ``cand``) together. Afterwards ``.rob`` /
        ``.sat`` are the restarted values and ``.step_rob`` / ``.step_sat`` those of ``states``."""
        done = np.asarray(done, dtype=bool)
        if not done.any():
            self.step(states, cand)
            return
        states = np.asarray(states, dtype=np.float64)
        c = np.asarray(cand, dtype=np.float64)
        self._cand = cand
        if self.static:
            rob, sat = self._eval_static(np.concatenate([states, c[done]]))
            B = self.B
            self.step_rob, self.step_sat = rob[:B], sat[:B]
            self.rob, self.sat = rob[:B].copy(), sat[:B].copy()
            self.rob[done], self.sat[done] = rob[B:], sat[B:]
            return
        rho, sat = self.mon.update_and_restart(states, done, c)
        self.step_rob, self.rob = rho, self.mon.robustness
        if self.satisfaction:
            self.step_sat, self.sat = sat, self.mon.satisfied
        else:
            self.step_sat = self.sat

    def restart(self, mask: np.ndarray, cand: Optional[np.ndarray] = None) -> None:
        """Restart the masked entries at ``cand [B, n]`` (default: the candidates of the last
        ``step``); their values become those of their step 0."""
        if not mask.any():
            return
        c = self._cand if cand is None else cand
        if c is None:
            raise ValueError("restart needs the initial states of the restarted entries (cand [B, n])")
        c = np.asarray(c, dtype=np.float64)
        if self.static:
            r, s = self._eval_static(c[mask])
            self.rob = self.rob.copy()
            self.sat = self.sat.copy()
            self.rob[mask], self.sat[mask] = r, s
            return
        self.mon.reset(mask)
        self._update(c, mask=mask)


# --------------------------------------------------------------------------------------------
# Rewards
# --------------------------------------------------------------------------------------------


#: The largest reward SB3 can store (its buffers are float32).
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _clip_finite(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    x = np.clip(x, lo, hi)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        x = np.where(np.isfinite(x), x, 0.0)
    return x


def parse_reward(text: str, dt: Optional[float] = None) -> RewardModel:
    """``"asap"``, ``"rho"``, ``"rho(window = 5)"``, ``"distance(lambda_t = 2, base = 1)"`` -> the
    model, read by the grammar's ``reward`` rule and checked as a spec's ``reward`` clause is
    (settings are constant expressions: numbers, ``pi``, ``e``, and ``dt`` when given, which a
    window in seconds such as ``rho(window = 1s)`` needs). Raises ValueError, one sentence."""
    from . import parser
    from .diagnostics import SpecError

    try:
        syn = parser.parse_reward(text)
    except SpecError as err:
        raise ValueError(f"cannot read the reward {text!r}: {err.diagnostics[0].message}; write e.g. asap, rho, "
                         "rho(window = 5), distance(lambda_t = 1)") from None
    return _checked(syn, text, dt)


def _checked(syn, text: str, dt: Optional[float]) -> RewardModel:
    from .checker import check_reward

    model, found = check_reward(syn, text, "--reward", dt)
    if model is None:
        d = next(d for d in found if d.is_error)
        where = "" if "reward" in d.message else f" in the reward {text!r}"  # `unknown constant 'x'`: where
        raise ValueError(d.message + where + (f"; {d.hint}" if d.hint else ""))
    return dataclasses.replace(model, span=None)  # no place in a file


def _checked_model(model: RewardModel, dt: Optional[float]) -> RewardModel:
    """A model built in Python, checked as a parsed one is."""
    from . import ast
    from .diagnostics import Span

    settings = []
    for k, v in model.params.items():
        try:
            value = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"reward setting {k} must be a number; got {v!r}") from None
        settings.append(ast.Setting(k, ast.Number(value, Span()), Span(), Span()))
    return _checked(ast.RewardSyntax(model.kind, tuple(settings), Span()), model.text, dt)


def resolve_reward(task: TaskModel, reward: Any = None, dt: Optional[float] = None) -> RewardModel:
    """The reward to use: the task's own, or ``reward`` (a kind, a text with settings, or a model),
    checked (``dt``: the system's step, for a window in seconds). Raises ValueError or TypeError."""
    if reward is None:
        return task.reward
    if isinstance(reward, RewardModel):
        return _checked_model(reward, dt)
    if not isinstance(reward, str):
        raise TypeError(f"reward must be a string such as 'asap' or 'rho(window = 5)'; got {type(reward).__name__}")
    model = parse_reward(reward, dt)
    if "(" not in reward and model.kind == task.reward.kind:
        return task.reward  # the task's own settings
    return model


def check_reward_fits(task: TaskModel, model: RewardModel) -> None:
    """Raise ValueError (one sentence) where ``model`` cannot be computed for ``task``: the
    distance reward measures to the regions of ``in R`` atoms, in ``asap`` and (if the task has
    one) in ``avoid``."""
    if model.kind != "distance":
        return
    if not task.asap_regions:
        raise ValueError(f"task {task.name}: the distance reward needs region atoms (`in R`) in `asap`, "
                         "and this task's asap has none; use reward asap or rho")
    if task.avoid is not None and not task.avoid_regions:
        raise ValueError(f"task {task.name}: the distance reward needs region atoms (`in R`) in `avoid`, "
                         "and this task's avoid has none")


class Reward:
    """Batched per-step reward of one kind, with the trackers it needs (besides ``asap``'s)."""

    def __init__(self, task: TaskModel, regions: Mapping[str, RegionModel], n_state: int, batch: int,
                 model: RewardModel, failure_reward: Optional[float] = None):
        check_reward_fits(task, model)
        self.task, self.model, self.kind, self.B = task, model, model.kind, int(batch)
        self.trackers: list[FormulaTracker] = []
        self.tracker: Optional[FormulaTracker] = None
        self.bounds = (-math.inf, math.inf)
        if self.kind == "asap":
            lo, hi = task.rho_bounds
            self.bounds = (lo, hi)
            self.auto = task.r_sat is None
            self.scale = task.rho_scale if self.auto else 1.0
            self.r_sat = float(task.r_sat_value)
            floor = lo * self.scale
        elif self.kind == "rho":
            window = model.params.get("window")
            if window is None:
                node = task.spec
            else:  # a window longer than any episode is the whole episode (and needs no more memory)
                iv = ir.Interval(0, min(int(window), task.deadline + 1) - 1)
                node = ir.Once(iv, task.asap)
                if task.avoid is not None:
                    node = ir.And(node, ir.Historically(iv, ir.Not(task.avoid)))
            node = ir.cap_past_windows(node, task.deadline)  # past windows inside asap/avoid too
            self.node = node
            self.bounds = formula_bounds(node)
            self.tracker = FormulaTracker(node, batch, n_state, satisfaction=False)
            self.trackers.append(self.tracker)
            floor = self.bounds[0]
        else:  # distance
            self.goal = [regions[r] for r in task.asap_regions]
            self.obstacles = [regions[r] for r in task.avoid_regions] if task.avoid is not None else []
            p = model.params
            self.lt, self.lo_, self.base = float(p.get("lambda_t", 1.0)), float(p.get("lambda_o", 1.0)), float(p.get("base", 0.0))
            floor = None
        if failure_reward is not None:
            floor = float(failure_reward)
            if not abs(floor) <= FLOAT32_MAX:
                raise ValueError(f"failure_reward must be a finite number within ±3.4e38 (a float32 reward); got {failure_reward!r}")
        self.floor = floor if floor is not None and math.isfinite(floor) else None

    @property
    def non_finite_value(self) -> float:
        """The reward of a step whose value is not finite: the failure reward, else 0."""
        return self.floor if self.floor is not None else 0.0

    # The env calls these in step with the trackers of asap; ``value`` reads them.
    def restart_all(self, states):
        for t in self.trackers:
            t.restart_all(states)

    def step(self, states, cand=None):
        for t in self.trackers:
            t.step(states, cand)

    def restart(self, mask, cand=None):
        for t in self.trackers:
            t.restart(mask, cand)

    def step_and_restart(self, states, done, cand):
        for t in self.trackers:
            t.step_and_restart(states, done, cand)

    def value(self, states: np.ndarray, asap_rob: np.ndarray, asap_sat: np.ndarray,
              failed: Optional[np.ndarray] = None) -> np.ndarray:
        """The reward of each entry for the step that reached ``states``."""
        if self.kind == "asap":
            rho = _clip_finite(asap_rob, *self.bounds) * self.scale
            r = np.where(asap_sat, self.r_sat, rho)
            if failed is not None and failed.any():
                r = np.where(failed, rho if self.floor is None else self.floor, r)
            return r
        if self.kind == "rho":
            r = _clip_finite(self.tracker.step_rob, *self.bounds)
        else:
            d_t = np.min([g.distance(states) for g in self.goal], axis=0)
            d_o = np.min([o.distance(states) for o in self.obstacles], axis=0) if self.obstacles else 0.0
            r = -self.lt * d_t + self.lo_ * d_o + self.base
        if failed is not None and failed.any() and self.floor is not None:
            r = np.where(failed, self.floor, r)
        return np.asarray(r, dtype=np.float64)


def make_reward(task: TaskModel, regions: Mapping[str, RegionModel], n_state: int, batch: int = 1,
                reward: Any = None, failure_reward: Optional[float] = None, dt: Optional[float] = None) -> Reward:
    """The :class:`Reward` of ``task`` for ``batch`` entries: its own, or ``reward`` (see
    :func:`resolve_reward`; ``dt`` for a window in seconds)."""
    return Reward(task, regions, n_state, batch, resolve_reward(task, reward, dt), failure_reward)


def reward_trace(program, task: str, trace: Any, reward: Any = None) -> np.ndarray:
    """Rewards of a whole trace ``[T, n]`` (or ``[B, T, n]``) step by step, as an env computes them:
    ``out[..., t-1]`` is the reward of the step reaching ``s_t`` (no failure handling)."""
    tr = np.asarray(trace, dtype=np.float64)
    single = tr.ndim == 2
    if single:
        tr = tr[None]
    B, T, n = tr.shape
    tm = program.task(task).model
    rw = make_reward(tm, program.regions, n, B, reward, dt=program.system.dt)
    asap = FormulaTracker(tm.asap, B, n)
    asap.restart_all(tr[:, 0])
    rw.restart_all(tr[:, 0])
    out = np.zeros((B, T - 1))
    for t in range(1, T):
        asap.step(tr[:, t])
        rw.step(tr[:, t])
        out[:, t - 1] = rw.value(tr[:, t], asap.rob, asap.sat)
    return out[0] if single else out
