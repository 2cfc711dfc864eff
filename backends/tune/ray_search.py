"""The tuning's search on a Ray cluster (``asapc tune --ray ADDRESS``): Ray Tune with its Optuna
searcher, on the tuning's own Optuna storage, so a call through Ray and one without continue the
same study.

Ray Tune runs each trial as a task of one CPU (:func:`.trial.run_trial`, reporting every
validation through ``ray.tune.report``); its median stopping rule prunes, as Optuna's
MedianPruner does here (the same warm-up: three trials, a third of the validations). The
searcher is told how each trial ended: complete with its score, pruned when the rule stopped
it, failed when the engine refused its settings, and otherwise (the time budget, Ctrl-C, a lost
node) left to be continued by the next call from its run directory. The trials' run directories
are the tune directory's, so on several machines it must be on storage they share (as the spec
file must be at the same path); the cluster is joined with
:func:`asap_dsl.backends.compare.cluster.connect`.
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path
from typing import Any, Callable, Optional

from .space import finite, sample, settings_id
from .study import STUDY, TuneError, continued_from
from .trial import TrialJob, TrialOutcome, job_for, run_trial

__all__ = ["search_ray"]


def _trainable(config: dict, job: TrialJob) -> None:
    """One trial in a Ray worker: train, report each validation, then the outcome."""
    from ray import tune

    settings = dict(config["settings"])
    job = dataclasses.replace(job, settings=settings, run_dir=str(Path(job.run_dir) / settings_id(settings)))

    def report(period: int, value: float, steps: int) -> bool:
        tune.report({"score": value, "period": period, "steps": steps, "final": 0})
        return False  # the scheduler stops the trial itself

    outcome = run_trial(job, report, None)
    last = outcome.curve[-1][0] if outcome.curve else 0  # the outcome one period on: a period is reported once
    tune.report({"score": outcome.score if finite(outcome.score) else 0.0, "period": last + 1, "final": 1,
                 **{k: v for k, v in outcome.to_dict().items() if k not in ("score", "curve")}})


def _dirname(trial) -> str:
    return f"trial-{trial.trial_id}"  # Tune's default name spells out every setting


def _baseline_task(job: TrialJob) -> dict:
    return run_trial(job, None, None).to_dict()


def _classes():
    from ray.tune.schedulers import MedianStoppingRule, TrialScheduler
    from ray.tune.search.optuna import OptunaSearch

    class Stopping(MedianStoppingRule):
        """Ray's median stopping rule, remembering the trials it stopped (pruned, not interrupted)."""

        def __init__(self, **kw):
            super().__init__(**kw)
            self.stopped: set[str] = set()

        def on_trial_result(self, tune_controller, trial, result):
            decision = super().on_trial_result(tune_controller, trial, result)
            if decision == TrialScheduler.STOP and not result.get("final"):
                self.stopped.add(trial.trial_id)
            return decision

    class Search(OptunaSearch):
        """Optuna's searcher for Ray Tune, telling the study how each trial ended."""

        def __init__(self, *args, tuning, stopping: Stopping, tell: Callable, deadline: Optional[float], **kw):
            super().__init__(*args, **kw)
            self.tuning, self.stopping, self.tell, self.deadline = tuning, stopping, tell, deadline

        def __getstate__(self) -> dict:  # Tune pickles its configuration: the driver's own objects stay out
            return {k: v for k, v in self.__dict__.items() if k not in ("tuning", "tell")}

        def save(self, checkpoint_path: str) -> None:
            pass  # the study is in the tuning's storage already; Tune's own restore is not used

        def save_to_dir(self, checkpoint_dir: str, session_str: str = "default") -> None:
            pass

        def suggest(self, trial_id: str) -> Optional[dict]:
            config = super().suggest(trial_id)
            ot = self._ot_trials.get(trial_id)
            if config is not None and ot is not None:
                self.tell("start", (ot.number + 1, config["settings"], continued_from(ot)))
            return config

        def on_trial_complete(self, trial_id: str, result: Optional[dict] = None, error: bool = False) -> None:
            ot = self._ot_trials.get(trial_id)
            if ot is None or trial_id in self._completed_trials:
                return super().on_trial_complete(trial_id, result, error)
            result = result or {}
            if result.get("final"):
                outcome = TrialOutcome(result.get("state", "complete"), result.get("score"), int(result.get("steps", 0)),
                                       float(result.get("seconds", 0.0)), result.get("error"))
                if outcome.state == "failed":
                    outcome.score = None
            elif trial_id in self.stopping.stopped:
                outcome = TrialOutcome("pruned", result.get("score"), int(result.get("steps", 0)),
                                       float(result.get("time_total_s", 0.0)))
            else:
                late = self.deadline is not None and time.monotonic() >= self.deadline
                outcome = TrialOutcome("cut" if late else "interrupted", result.get("score"), int(result.get("steps", 0)),
                                       float(result.get("time_total_s", 0.0)))
            self.tuning.record(ot, outcome, ot.user_attrs.get("settings", {}))
            self._completed_trials.add(trial_id)
            records = self.tuning.records()
            mine = [r for r in records if r.number == ot.number + 1]
            if mine:
                self.tell("trial", mine[0])

    return Stopping, Search


def search_ray(tuning, address: str, trials: int, time_limit: Optional[float], tell: Callable[[str, Any], None],
               timeout: float = 30.0):
    """Run the tuning's remaining trials through Ray Tune on the cluster at ``address``
    (``local``: one of this machine), the task's own block first where it has not been scored.
    Returns the :class:`~.study.TuneResult`; :class:`~asap_dsl.backends.compare.cluster.ClusterError`
    when the cluster cannot be joined, :class:`~.study.TuneError` when Ray Tune is missing."""
    from asap_dsl.backends.compare.cluster import connect

    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # Tune's tables are not this command's progress lines
    try:
        import ray
        from ray import tune
    except ImportError:
        raise TuneError("--ray needs Ray Tune: pip install 'asap-dsl[ray]'") from None
    optuna = tuning.optuna
    deadline = None if time_limit is None else tuning.started + time_limit
    tuning.recover()
    first = tuning.first_ray_trial = len(tuning.study.trials)  # the trials from here on are this call's
    connected = connect(address, timeout)
    try:
        base = job_for(tuning.setup, {}, tuning.directory / "start")
        start = tuning.baseline_done()
        pending = None if start is not None else ray.remote(num_cpus=1)(_baseline_task).remote(base)
        left = trials - tuning.done_count()
        stopped = None
        if left > 0 and (deadline is None or time.monotonic() < deadline):
            stopped = _fit(tuning, tune, optuna, STUDY, left, deadline, tell)
        elif left > 0:
            stopped = "time"
        if pending is not None:
            outcome = TrialOutcome(**{k: v for k, v in ray.get(pending).items()})
            tell("baseline", outcome)
            start = outcome.score if outcome.state == "complete" else None
        else:
            tell("baseline", TrialOutcome("complete", start))
        tuning.save_best(start)
        if stopped is None and tuning.done_count() < trials:
            stopped = "time" if deadline is not None and time.monotonic() >= deadline else "interrupted"
        return tuning.result(trials, start, stopped, frozenset(range(first, len(tuning.study.trials))))
    finally:
        if connected:
            ray.shutdown()


def _fit(tuning, tune, optuna, study_name: str, left: int, deadline: Optional[float], tell) -> Optional[str]:
    """Ray Tune over ``left`` trials; "interrupted" when Ctrl-C ended it, else None."""
    Stopping, Search = _classes()
    setup = tuning.setup
    ctx = setup.context()

    def space(trial):  # pickled with the searcher: it holds nothing of the driver's
        settings = sample(trial, ctx)
        trial.set_user_attr("settings", settings)
        return {"settings": settings}

    stopping = Stopping(time_attr="period", metric="score", mode="max",
                        grace_period=max(1, setup.validations // 3), min_samples_required=3)
    sampler = optuna.samplers.TPESampler(n_startup_trials=5, multivariate=True,
                                         seed=(setup.seed * 1_000_003 + tuning.first_ray_trial) % 2**32)
    search = Search(space=space, metric="score", mode="max", sampler=sampler, study_name=study_name,
                    storage=tuning.storage, tuning=tuning, stopping=stopping, tell=tell, deadline=deadline)
    job = job_for(setup, {}, tuning.directory / "trials")
    sessions = tuning.directory / "ray"
    name = f"session-{len(list(sessions.iterdir())) + 1 if sessions.is_dir() else 1}"
    budget = None if deadline is None else max(1.0, deadline - time.monotonic())
    tuner = tune.Tuner(
        tune.with_resources(tune.with_parameters(_trainable, job=job), {"cpu": 1}),
        tune_config=tune.TuneConfig(search_alg=search, scheduler=stopping, num_samples=left, time_budget_s=budget,
                                    trial_dirname_creator=_dirname),
        run_config=tune.RunConfig(name=name, storage_path=str(sessions.resolve()), verbose=0))
    try:
        tuner.fit()
    except KeyboardInterrupt:
        return "interrupted"
    return None
