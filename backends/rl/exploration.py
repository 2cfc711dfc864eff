"""Sparse goals: the oracle's demonstrations when a run's own exploration has found nothing.

SAC explores with Gaussian noise drawn afresh at every step. Where the goal needs a detour — the
mountain car must swing back up the left slope before it can climb the right one — such noise
does not reach it, and the learner settles on the best of the dense part of the reward (pushing
towards the goal and stalling on the slope: 0% at every tolerance, docs/training.md, "Sparse
goals: the mountain car"). The oracle's action sequences are exact witnesses of the goal
(:mod:`.demonstrations`); a few of them in the replay buffer show the critic what reaching it
earns, and the policy's own successes follow.

**The rule** (the default preset's ``late_demonstrations`` and ``late_after``): at a validation,
when no validation of the run so far has brought a single state into the goal within any
tolerance and the run has spent at least ``late_after`` of its budget (its steps, or its time
limit, whichever is further along), the oracle solves ``late_demonstrations`` initial states of
the run's own demonstration seed (:func:`~.demonstrations.demonstration_seed`: never the
validation or evaluation states) and their replays go into the replay buffer. Once per run; its
time counts as the run's. A run whose validations succeed never triggers it — the benchmarks'
first validation already does — so it costs them nothing. Where demonstrations cannot be had (a
black box, PPO or A2C) or the run asked for its own (``--demonstrations N``, 0 included) there
is no rule.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Optional, Sequence

__all__ = ["LATE_STATE_SECONDS", "LateDemonstrations", "add_late"]

#: The oracle's time per state for late demonstrations: larger than at the start of a run
#: (:data:`~.demonstrations.DEMONSTRATION_STATE_SECONDS`), since a run that triggers the rule has
#: nothing better to do with it (the mountain car's states take 3.5-10 s each).
LATE_STATE_SECONDS = 15.0


class _Stopped(Exception):
    """A stop was requested while the oracle searched: the rule is left for a resumed run."""


@dataclass
class LateDemonstrations:
    """The rule for one run: ``states`` to solve, once ``after`` of the budget is spent with no
    success; ``added`` what was done when it fired (kept in the checkpoint), None before."""

    states: int
    after: float
    added: Optional[dict] = None

    def due(self, curves: Sequence[Mapping[str, Any]], steps: int, total_steps: int, seconds: float,
            time_limit: Optional[float]) -> bool:
        """Whether the rule fires after the validations ``curves`` (the latest last), at ``steps``
        of ``total_steps`` and ``seconds`` of ``time_limit`` (None: a run bounded by steps)."""
        if self.added is not None or self.states <= 0 or not curves:
            return False
        if any(rate > 0 for row in curves for rate in row["rates"].values()):
            return False
        spent = steps / max(1, total_steps)
        if time_limit is not None:
            spent = max(spent, seconds / time_limit)
        return spent >= self.after


def add_late(session, model, steps: int) -> Optional[dict]:
    """Fire ``session.late``: the oracle's sequences for its states into ``model``'s replay buffer,
    said in the progress and recorded in the manifest (``late_demonstrations``). Returns what was
    added (:class:`~.demonstrations.Demonstrations` as a dict with ``at_step``), or None when a
    stop was requested meanwhile (the rule then stays due)."""
    from .demonstrations import add_demonstrations, searcher, solve

    rule: LateDemonstrations = session.late
    cfg = session.cfg

    def check_stop() -> None:
        if session.stop.requested:
            raise _Stopped

    who = searcher(session.prog)
    session._tell(f"no validation has succeeded after {steps:,} steps: the {who} on {rule.states} initial states "
                  f"of the run's own seed for demonstrations ...")
    try:
        # The oracle in one process: forking one that runs a learner (JAX's or torch's threads) is
        # not safe. The planner's workers are spawned.
        witnesses = solve(session.prog, cfg.task, rule.states, cfg.seed, workers=None if who == "planner" else 1,
                          state_seconds=LATE_STATE_SECONDS, check_stop=check_stop)
    except _Stopped:
        return None
    demos = add_demonstrations(session.prog, cfg.task, model, session.learner_env, session.scaling, witnesses,
                               reward=cfg.reward, failure_reward=cfg.failure_reward)
    rule.added = {**demos.to_dict(), "at_step": int(steps)}
    session._tell(demos.text())
    session.run.update_manifest(late_demonstrations=rule.added)
    return rule.added
