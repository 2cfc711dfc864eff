"""One batched rollout for every controller.

Evaluation (``asapc eval``), training's periodic validation and ``asapc compare`` all judge a
controller here, on the same rules: every initial state starts at once in one batch of the
task's environment (no autoreset), the episode lasts the task's deadline, the controller is
called once per step for the whole batch, and an entry's episode ends at its first failure
(``avoid``, leaving the state space, a non-finite state) or at the deadline.

Success at tolerance T (docs/training.md, "Evaluation"): ``asap`` holds at some step
``<= T`` with no ``avoid`` hit and no exit from the state space before it. ``t_reach`` is that
first step (``inf`` if none).

A **controller** is anything with ``reset(states)`` (the initial states of the batch, called once)
and ``act(obs, states, t) -> actions [B, m]``: ``obs`` is what the environment shows an agent
(float32, as in training), ``states`` the true states (for controllers that may know them, such
as the oracle's replay), ``t`` the step about to be taken (0, 1, ...).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Protocol, Sequence

import numpy as np

__all__ = ["Controller", "Evaluator", "RolloutResult", "rollout"]


class Controller(Protocol):
    def reset(self, states: np.ndarray) -> None:
        """The initial states ``[B, n]`` of a new batch of episodes."""

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        """Actions ``[B, m]`` for step ``t`` (in the action space's units; they are clipped)."""


@dataclass
class RolloutResult:
    """Per initial state: when ``asap`` first held, how the episode ended, and its return."""

    initial_states: np.ndarray  # [N, n]
    t_reach: np.ndarray         # [N] float: first step asap held before any failure; inf if never
    end_reason: np.ndarray      # [N] str: avoid | out_of_bounds | non_finite | time_limit
    end_step: np.ndarray        # [N] int: the step the episode ended at
    returns: np.ndarray         # [N] undiscounted sum of the task's reward up to the end
    steps: int                  # the episode length (the deadline)
    trajectories: Optional[np.ndarray] = None  # [N, steps + 1, n], NaN after the end (record=True)
    actions: Optional[np.ndarray] = None       # [N, steps, m], NaN after the end (record=True)
    rho: Optional[np.ndarray] = None           # [N, steps + 1] ρ of asap, NaN from a failure or the end (robustness=True)

    @property
    def episodes(self) -> int:
        return len(self.t_reach)

    def successes(self, tolerance: int) -> np.ndarray:
        """Which states succeed at tolerance ``T``: ``t_reach <= T``."""
        return self.t_reach <= tolerance

    def rate(self, tolerance: int) -> float:
        return float(np.mean(self.successes(tolerance))) if self.episodes else float("nan")

    def failures(self) -> dict[str, int]:
        """Episodes that ended in a failure before reaching, by reason."""
        out = {}
        for reason in ("avoid", "out_of_bounds", "non_finite"):
            out[reason] = int(np.sum((self.end_reason == reason) & ~np.isfinite(self.t_reach)))
        out["not_reached"] = int(np.sum((self.end_reason == "time_limit") & ~np.isfinite(self.t_reach)))
        return out


class Evaluator:
    """A fixed batch of initial states of one task, ready to judge any number of controllers.

    The environment (simulator, monitors, reward) is built once; each :meth:`run` restarts it at
    the same states, so that every controller is judged on exactly the same episodes.
    """

    def __init__(self, program, task: Optional[str], states: np.ndarray, reward: Any = None,
                 steps: Optional[int] = None, engine: Optional[str] = None):
        from .env import EnvCore
        from .native import with_engine

        self.states = np.asarray(states, dtype=np.float64)
        if self.states.ndim != 2 or len(self.states) == 0:
            raise ValueError(f"initial states must be a non-empty [N, n] array; got shape {self.states.shape}")
        # Compiled where it covers the task (``engine`` as make_vec_env takes it): a validation
        # of 500 states then costs a few milliseconds per step instead of a few tens.
        self.core = with_engine(EnvCore(program, task, len(self.states), reward, autoreset=False), engine)
        if self.states.shape[1] != self.core.n:
            raise ValueError(f"initial states have {self.states.shape[1]} entries; the system has {self.core.n} states")
        self.task = self.core.task
        self.steps = int(steps if steps is not None else self.task.model.deadline)
        if self.steps < 1:
            raise ValueError(f"steps must be at least 1; got {self.steps}")

    @property
    def observation_space(self):
        return self.core.observation_space

    @property
    def action_space(self):
        return self.core.action_space

    def run(self, controller: Controller, record: bool = False, *, states: Optional[np.ndarray] = None,
            steps: Optional[int] = None, robustness: bool = False) -> RolloutResult:
        """Roll every state out under ``controller``; one ``act`` call per step for the batch.

        ``states``: other initial states of the same shape (the environment is reused: the
        planner judges each batch of candidates here); ``steps``: a shorter or longer episode;
        ``robustness``: also keep ρ of ``asap`` at every step (the planner's search signal).
        """
        from .env import END_REASONS

        core, N = self.core, len(self.states)
        T = self.steps if steps is None else int(steps)
        x0 = self.states if states is None else np.asarray(states, dtype=np.float64)
        if x0.shape != self.states.shape or T < 1:
            raise ValueError(f"states must have shape {self.states.shape} and steps be at least 1; got "
                             f"{x0.shape} and {T}")
        obs = core.start(x0, T)
        controller.reset(core.states.copy())
        t_reach = np.where(core.asap.sat, 0.0, np.inf)
        end = np.zeros(N, dtype=np.int64)       # 0 while running, else an index into END_REASONS
        end_step = np.full(N, T, dtype=np.int64)
        returns = np.zeros(N)
        m = core.system.n_action
        traj = acts = None
        if record:
            traj = np.full((N, T + 1, core.n), np.nan)
            acts = np.full((N, T, m), np.nan)
            traj[:, 0] = core.states
        rho = None
        if robustness:
            rho = np.full((N, T + 1), np.nan)
            rho[:, 0] = core.asap.rob
        for t in range(T):
            running = end == 0
            if not running.any():
                break
            a = np.asarray(controller.act(obs, core.states.copy(), t), dtype=np.float64).reshape(N, m)
            a = np.clip(a, core.system.action_low, core.system.action_high)
            obs, r, failed, _, _, done = core.step(a)
            returns[running] += r[running]
            newly = running & core.asap.step_sat & ~failed & ~np.isfinite(t_reach)
            t_reach[newly] = t + 1
            finished = running & done
            end[finished] = core.info_end[finished]
            end_step[finished] = t + 1
            if record:
                traj[running, t + 1] = core.states[running]
                acts[running, t] = a[running]
            if rho is not None:
                ok = running & ~failed
                rho[ok, t + 1] = core.asap.step_rob[ok]
        end[end == 0] = 4  # time_limit (never reached when every entry ran the full T steps)
        reasons = np.array([END_REASONS[i] for i in end], dtype=object)
        return RolloutResult(x0.copy(), t_reach, reasons, end_step, returns, T, traj, acts, rho)


def rollout(program, task: Optional[str], controller: Controller, states: np.ndarray, reward: Any = None,
            steps: Optional[int] = None, record: bool = False) -> RolloutResult:
    """Roll ``states`` out under ``controller`` once, all in one batch, on the rules of the
    module docstring (:class:`Evaluator` builds the environment once for many controllers).

    :param program: a :class:`asap_dsl.Program`
    :param task: the task's name; None for a spec with one task (KeyError for an unknown one)
    :param controller: anything with ``reset(states)`` and ``act(obs, states, t) -> actions``
        (:class:`Controller`)
    :param states: the initial states, ``[N, n]`` (N at least 1; ValueError otherwise)
    :param reward: None for the task's own reward, or a reward as :func:`asap_dsl.make_env`
        takes it (what ``returns`` sums)
    :param steps: the episode length; None for the task's deadline
    :param record: also keep every state and action (``trajectories``, ``actions``)
    :return: per initial state, when ``asap`` first held, how and when the episode ended and its
        return (:class:`RolloutResult`)
    """
    return Evaluator(program, task, states, reward, steps).run(controller, record)


class ConstantController:
    """The same action everywhere (a baseline, and the simplest controller for tests)."""

    def __init__(self, action: Sequence[float]):
        self.action = np.asarray(action, dtype=np.float64)

    def reset(self, states: np.ndarray) -> None:
        self.B = len(states)

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        return np.broadcast_to(self.action, (len(states), self.action.size))
