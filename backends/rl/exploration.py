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
the start, ``black_box_demonstrations_when``): at a validation, once per run, the first of

- *nothing found*: no validation of the run so far has brought a single state into the goal
  within any tolerance and the run has spent at least ``late_after`` of its budget (its steps, or
  its time limit, whichever is further along): the oracle solves ``late_demonstrations`` initial
  states (15 s each at most) and their replays go into the replay buffer;
- *stalled*: validation has stopped improving as the plateau rule judges it
  (:func:`~.validation.plateau_reached`, the run's share; the plateau's floor does not apply):
  the oracle solves ``stall_demonstrations`` states within the demonstrations' budget, and the
  longest share of their sequences go in, each repeated (as demonstrations from the start do).

The states are the run's own demonstration seed's (:func:`~.demonstrations.demonstration_seed`:
never the validation or evaluation states). Its time counts as the run's, and the run is judged
for its plateau on the validations after it alone. Where demonstrations cannot be had (PPO or
A2C) or the run asked for its own (``--demonstrations N``, 0 included) there is no rule.
"""

from __future__ import annotations

from dataclasses import dataclass
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
    share of the steps (0 or None: not on a stall); ``added`` what was done when it fired (kept in
    the checkpoint), None before."""

    states: int
    after: float
    stall_states: int = 0
    stall: Optional[float] = None
    added: Optional[dict] = None

    @property
    def waits_for_stall(self) -> bool:
        """Whether a stall would still fire the rule (a run then does not end on its plateau)."""
        return self.added is None and self.stall_states > 0 and self.stall is not None

    def due(self, curves: Sequence[Mapping[str, Any]], steps: int, total_steps: int, seconds: float,
            time_limit: Optional[float]) -> Optional[str]:
        """Why the rule fires after the validations ``curves`` (the latest last), at ``steps`` of
        ``total_steps`` and ``seconds`` of ``time_limit`` (None: a run bounded by steps):
        :data:`NOTHING` or :data:`STALLED`; None when it does not."""
        from .validation import plateau_reached

        if self.added is not None or not curves:
            return None
        if not any(rate > 0 for row in curves for rate in row["rates"].values()):
            spent = steps / max(1, total_steps)
            if time_limit is not None:
                spent = max(spent, seconds / time_limit)
            return NOTHING if self.states > 0 and spent >= self.after else None
        if self.waits_for_stall and plateau_reached(list(curves), steps, float(self.stall)):
            return STALLED
        return None


def add_late(session, model, steps: int, why: str = NOTHING) -> Optional[dict]:
    """Fire ``session.late`` for the reason ``why``: the oracle's sequences for its states into
    ``model``'s replay buffer, said in the progress and recorded in the manifest
    (``late_demonstrations``). Returns what was added (:class:`~.demonstrations.Demonstrations` as
    a dict with ``at_step`` and ``why``), or None when a stop was requested meanwhile (the rule then
    stays due)."""
    from .demonstrations import DEMONSTRATION_STATE_SECONDS, add_demonstrations, longest, search_count, searcher, solve

    rule: LateDemonstrations = session.late
    cfg = session.cfg
    stalled = why == STALLED
    states = rule.stall_states if stalled else rule.states

    def check_stop() -> None:
        if session.stop.requested:
            raise _Stopped

    who = searcher(session.prog)
    budget = cfg.demonstration_seconds if stalled else None
    per_state = DEMONSTRATION_STATE_SECONDS if stalled else LATE_STATE_SECONDS
    head = (f"validation stopped improving after {steps:,} steps" if stalled
            else f"no validation has succeeded after {steps:,} steps")
    count = search_count(session.prog, states, per_state, budget)
    session._tell(f"{head}: the {who} on {count:,} initial states of the run's own seed for demonstrations"
                  + ("" if budget is None else f", for at most {budget:.0f} s") + " ...")
    try:
        # The oracle in one process: forking one that runs a learner (JAX's or torch's threads) is
        # not safe. The planner's workers are spawned.
        witnesses = solve(session.prog, cfg.task, states, cfg.seed, workers=None if who == "planner" else 1,
                          state_seconds=per_state, budget_seconds=budget, check_stop=check_stop)
    except _Stopped:
        return None
    if stalled:  # as demonstrations from the start: the long manoeuvres, weighted
        witnesses = longest(witnesses, cfg.demonstration_share, cfg.demonstration_repeat)
    demos = add_demonstrations(session.prog, cfg.task, model, session.learner_env, session.scaling, witnesses,
                               reward=cfg.reward, failure_reward=cfg.failure_reward)
    rule.added = {**demos.to_dict(), "at_step": int(steps), "why": why}
    session._tell(demos.text())
    session.run.update_manifest(late_demonstrations=rule.added)
    return rule.added
