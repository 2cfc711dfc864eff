"""Demonstrations when a run needs them: the oracle's action sequences once its own exploration
has found nothing, or once its validation has stopped improving.

SAC explores with Gaussian noise drawn afresh at every step. Where the goal needs a detour — the
mountain car must swing back up the left slope before it can climb the right one — such noise
does not reach it, and the learner settles on the best of the dense part of the reward (pushing
towards the goal and stalling on the slope: 0% at every tolerance, docs/training.md, "Sparse
goals: the mountain car"). Where it reaches the goal only from easy states — the swimmer's strokes
(18% within 30 steps, flat for a million steps) — its own successes do not teach the rest. The
oracle's action sequences (the planner's on a black box) are exact witnesses of the goal
(:mod:`.demonstrations`); in the replay buffer they show the critic what reaching it earns, and
the policy's own successes follow. Where the learner needs none — the DC motor comes within 5
points of its ceiling in 9-12 s without them, and 54 s with them from the start (their search and
the buffer's bias towards long manoeuvres, ``benchmarks/train.py``) — they cost time and nothing else.

**The rule** (the default preset's ``late_demonstrations``, ``late_after`` and ``demonstrations``
with ``demonstrations_when = "stall"``, on known dynamics: on a black box the planner's come at
the start, ``black_box_demonstrations_when``): at a validation, each trigger at most once per run,

- *nothing found*: no validation of the run so far has brought a single state into the goal
  within any tolerance and the run has spent at least ``late_after`` of its budget (its steps, or
  its time limit, whichever is further along): the oracle solves ``late_demonstrations`` initial
  states (15 s each at most) and their replays go into the replay buffer. Such a task is one whose
  dense reward leads away from the goal (a swing-up, a detour), so the discount's horizon, a share
  of the deadline chosen for tasks where it does not, grows to the preset's ``sparse_horizon``
  share (the run's ``sparse_gamma``; not where the run set its own ``gamma``); and where the
  preset's ``sparse_imitation`` is on (SAC on sbx), the oracle solves as many of
  ``imitation_states`` as the imitation's budget buys instead (on every core), all their paths go
  into the replay buffer (grown for them) and the actor imitates them from then on (:mod:`.imitation`);
- *stalled*: validation has stopped improving as the plateau rule judges it
  (:func:`~.validation.plateau_reached`, the run's share, on the validations since the last
  firing; the plateau's floor does not apply) and some tolerance is still short of 100% — a
  run that still finds nothing after the first trigger's sequences stalls too:
  the oracle solves ``stall_demonstrations`` states within the demonstrations' budget, and the
  longest share of their sequences go in, each repeated (as demonstrations from the start do).

A run that found nothing can thus stall later too, and get both: the first few sequences show the
critic what the goal pays, the later ones the long manoeuvres its own successes did not teach.
The states are the run's own demonstration seed's (:func:`~.demonstrations.demonstration_seed`:
never the validation or evaluation states). Its time counts as the run's, and the run is judged
for its plateau on the validations after the last firing alone. Where demonstrations cannot be
had (PPO or A2C) or the run asked for its own (``--demonstrations N``, 0 included) there is no rule.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Sequence

__all__ = ["LATE_STATE_SECONDS", "NOTHING", "STALLED", "LateDemonstrations", "add_late"]

#: The oracle's time per state for late demonstrations: larger than at the start of a run
#: (:data:`~.demonstrations.DEMONSTRATION_STATE_SECONDS`), since a run that triggers the rule has
#: nothing better to do with it (the mountain car's states take 3.5-10 s each).
LATE_STATE_SECONDS = 15.0


class _Stopped(Exception):
    """A stop was requested while the oracle searched: the rule is left for a resumed run."""


#: Why the rule fired: nothing found (the sparse goal's trigger), or validation stalled.
NOTHING, STALLED = "nothing found", "stalled"


@dataclass
class LateDemonstrations:
    """The rule for one run: ``states`` to solve once ``after`` of the budget is spent with no
    success, ``stall_states`` once validation has stopped improving over the latest ``stall``
    share of the steps (0 or None: not on a stall); ``sparse_gamma`` the discount once nothing was
    found (None: the run's own). ``added`` what each firing did, in order (kept in the checkpoint)."""

    states: int
    after: float
    stall_states: int = 0
    stall: Optional[float] = None
    sparse_gamma: Optional[float] = None
    imitation: float = 0.0  # the actor's weight on the paths found once nothing was (0: a few sequences alone)
    imitation_states: int = 0
    added: list[dict] = field(default_factory=list)

    def fired(self, why: str) -> bool:
        """Whether the trigger ``why`` has fired in this run."""
        return any(row.get("why") == why for row in self.added)

    @property
    def since(self) -> Optional[int]:
        """The step of the latest firing (None before any): validations after it judge the run."""
        return int(self.added[-1]["at_step"]) if self.added else None

    @property
    def gamma(self) -> Optional[float]:
        """The discount a firing set (None: the run's own)."""
        return next((row["gamma"] for row in reversed(self.added) if row.get("gamma") is not None), None)

    @property
    def imitated(self) -> Optional[dict]:
        """The firing whose paths the actor imitates (None: none)."""
        return next((row for row in self.added if row.get("imitation")), None)

    @property
    def waits_for_stall(self) -> bool:
        """Whether a stall would still fire the rule (a run then does not end on its plateau)."""
        return self.stall_states > 0 and self.stall is not None and not self.fired(STALLED)

    def restore(self, stored: Any) -> None:
        """What a checkpoint kept: a list of firings, or one (a run from before both could fire)."""
        self.added = [] if stored is None else [dict(stored)] if isinstance(stored, Mapping) else [dict(r) for r in stored]

    def recent(self, curves: Sequence[Mapping[str, Any]]) -> list:
        """The validations since the latest firing (all of them before any)."""
        since = self.since
        return [r for r in curves if since is None or r["steps"] > since]

    def may_fire(self, curves: Sequence[Mapping[str, Any]]) -> bool:
        """Whether the rule may still fire after the validations ``curves``: a run does not end
        on its plateau before (it has found nothing and nothing has fired, or a stall would)."""
        if not _succeeded(curves):
            return not self.added or self.waits_for_stall
        return self.waits_for_stall and not _complete(self.recent(curves) or curves)

    def due(self, curves: Sequence[Mapping[str, Any]], steps: int, total_steps: int, seconds: float,
            time_limit: Optional[float], interval: int = 0) -> Optional[str]:
        """Why the rule fires after the validations ``curves`` (the latest last), at ``steps`` of
        ``total_steps`` and ``seconds`` of ``time_limit`` (None: a run bounded by steps):
        :data:`NOTHING` or :data:`STALLED`; None when it does not, also when fewer than
        ``interval`` steps (a validation interval) are left: the run could not learn from them."""
        from .validation import plateau_reached

        if not curves or total_steps - steps < interval:
            return None
        if not _succeeded(curves) and not self.fired(NOTHING):
            spent = steps / max(1, total_steps)
            if time_limit is not None:
                spent = max(spent, seconds / time_limit)
            return NOTHING if self.states > 0 and spent >= self.after else None
        if self.may_fire(curves) and plateau_reached(self.recent(curves), steps, float(self.stall)):
            return STALLED
        return None


def _succeeded(curves: Sequence[Mapping[str, Any]]) -> bool:
    """Whether any validation brought a state into the goal within any tolerance."""
    return any(rate > 0 for row in curves for rate in row["rates"].values())


def _complete(curves: Sequence[Mapping[str, Any]]) -> bool:
    """Whether the best validation is 100% at every tolerance: no demonstration can add to it."""
    return all(rate >= 1.0 for rate in max(curves, key=lambda r: r["score"])["rates"].values())


def add_late(session, model, steps: int, why: str = NOTHING) -> Optional[dict]:
    """Fire ``session.late`` for the reason ``why``: the oracle's sequences for its states into
    ``model``'s replay buffer (after the longer discount where nothing was found), said in the
    progress and recorded in the manifest (``late_demonstrations``, the list of firings). Returns
    what was added (:class:`~.demonstrations.Demonstrations` as a dict with ``at_step``, ``why``
    and any new ``gamma``), or None when a stop was requested meanwhile (the rule then stays due)."""
    from .demonstrations import DEMONSTRATION_STATE_SECONDS, add_demonstrations, longest, search
    from .imitation import IMITATION_STATE_SECONDS, set_imitation

    rule: LateDemonstrations = session.late
    cfg = session.cfg
    stalled = why == STALLED
    imitated = not stalled and rule.imitation > 0 and rule.imitation_states > 0
    states = rule.stall_states if stalled else rule.imitation_states if imitated else rule.states

    def check_stop() -> None:
        if session.stop.requested:
            raise _Stopped

    began = time.perf_counter()
    head = (f"validation stopped improving after {steps:,} steps" if stalled
            else f"no validation has succeeded after {steps:,} steps")
    # It keeps the oracle's second initial guess per horizon, which `--imitation`'s search drops:
    # along a long tour of warm starts, the pendulum's paths without it degraded to 42% within 65
    # steps on one seed's states (72% solved afresh); with it 520 states in 730 s, 71% within 65,
    # and the run gained 10 / 17 / 8 points (docs/training.md).
    try:
        witnesses = search(session.prog, cfg.task, states, cfg.seed, session._tell, head,
                           state_seconds=(DEMONSTRATION_STATE_SECONDS if stalled else IMITATION_STATE_SECONDS
                                          if imitated else LATE_STATE_SECONDS),
                           budget_seconds=(cfg.demonstration_seconds if stalled else cfg.imitation_seconds
                                           if imitated else None),
                           time_limit=cfg.time_limit, check_stop=check_stop)
    except _Stopped:
        return None
    if stalled:  # as demonstrations from the start: the long manoeuvres, weighted
        witnesses = longest(witnesses, cfg.demonstration_share, cfg.demonstration_repeat)
    gamma = None
    if not stalled and rule.sparse_gamma is not None and rule.sparse_gamma > float(model.gamma):
        gamma = float(rule.sparse_gamma)
        session._tell(f"the discount's horizon grows to the deadline: gamma {float(model.gamma):g} -> {gamma:g}")
        session.set_discount(model, gamma)
    demos = add_demonstrations(session.prog, cfg.task, model, session.learner_env, session.scaling, witnesses,
                               reward=cfg.reward, failure_reward=session.failure_reward, grow=imitated)
    # Charged the search's seconds, as at the start: read back from the cache it took none here.
    session.seconds_before += max(0.0, demos.seconds - (time.perf_counter() - began))
    row = {**demos.to_dict(), "at_step": int(steps), "why": why, **({} if gamma is None else {"gamma": gamma})}
    rule.added.append(row)
    session._tell(demos.text())
    if imitated and demos.rows > 0:
        row["imitation"] = float(rule.imitation)
        set_imitation(model, rule.imitation, demos.rows, demos.start_row)
        session._tell(f"the actor imitates these paths from now on (weight {rule.imitation:g})")
    session.run.update_manifest(late_demonstrations=rule.added)
    return row
