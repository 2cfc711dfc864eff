"""One tuning trial: a training run of the task with the trial's settings, in its own run
directory, scored on the run's validation states and reported validation by validation.

The score is the run's best validation score (:func:`asap_dsl.backends.rl.validation_score`: the
mean success rate over the task's tolerances on the validation states, seed 7): the run keeps
that model, so it is what the settings deliver. The evaluation states (seed 2024) are never
touched. After each validation ``report(period, best_so_far, steps)`` is called (``period``: the
validation's step divided by the run's validation interval, so trials of one tuning compare at
the same points); it returns True to prune, and the run then ends at once, as does a run past
``deadline`` (``time.monotonic()``). A directory that already holds a run of these settings is
continued from its checkpoint (or read, when it has finished), so an interrupted trial resumes.

This module is what a Ray worker imports: no Optuna, no Ray.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

__all__ = ["TrialJob", "TrialOutcome", "run_trial"]

#: ``report(period, best_so_far, steps) -> prune?``
Reporter = Callable[[int, float, int], bool]


@dataclass(frozen=True)
class TrialJob:
    """What a trial trains: the spec, task and run settings of the tuning, the trial's settings."""

    spec_file: str
    task: str
    algo: str
    engine: str
    steps: int
    n_envs: int
    seed: int
    settings: dict
    run_dir: str


@dataclass
class TrialOutcome:
    """How a trial ended: ``complete``, ``pruned``, ``cut`` (the tuning's time ran out),
    ``interrupted`` (Ctrl-C / SIGTERM) or ``failed`` (the engine refused the settings: ``error``)."""

    state: str
    score: Optional[float] = None
    steps: int = 0
    seconds: float = 0.0
    error: Optional[str] = None
    curve: list = field(default_factory=list)  # (period, best so far) per validation

    def to_dict(self) -> dict:
        return {"state": self.state, "score": self.score, "steps": self.steps, "seconds": self.seconds,
                "error": self.error, "curve": self.curve}


class _Watch:
    """The run's progress as the trial sees it: each validation reported, pruning remembered."""

    def __init__(self, report: Optional[Reporter], every: int, deadline: Optional[float]):
        self.report, self.every, self.deadline = report, max(1, every), deadline
        self.best = float("-inf")
        self.period = 0
        self.pruned = self.cut = False
        self.curve: list = []

    def seen(self, steps: int, score: float) -> None:
        self.best = max(self.best, float(score))
        period = max(1, int(steps) // self.every)
        if period <= self.period:  # a validation within the same interval (on the clock): reported once
            return
        self.period = period
        self.curve.append((period, self.best))
        if self.report is not None and not self.pruned and self.report(period, self.best, int(steps)):
            self.pruned = True

    # TrainProgress
    def start(self, config, done: int, ceiling) -> None:
        pass

    def advance(self, done: int) -> None:
        pass

    def validated(self, row: dict) -> None:
        self.seen(row["steps"], row["score"])

    def finish(self) -> None:
        pass

    def stop_now(self) -> bool:
        if self.deadline is not None and time.monotonic() >= self.deadline:
            self.cut = True
        return self.pruned or self.cut


def _stopper(watch: _Watch):
    from stable_baselines3.common.callbacks import BaseCallback

    class Stop(BaseCallback):
        """Ends the run (as finished) once the trial is pruned or the tuning's time is up."""

        def _on_step(self) -> bool:
            return not watch.stop_now()

    return Stop()


def _past_curve(run_dir: Path) -> list[tuple[int, float]]:
    """The (steps, score) of the validations a run directory already holds."""
    from asap_dsl.runs import RunError
    from asap_dsl.runschema import read_curves

    try:
        return [(int(r["steps"]), float(r["score"])) for r in read_curves(run_dir / "curves.csv")]
    except (RunError, KeyError, ValueError):
        return []


def run_trial(job: TrialJob, report: Optional[Reporter] = None, deadline: Optional[float] = None) -> TrialOutcome:
    """Train (or continue, or read) the trial's run and score it (the module's rules).
    :class:`asap_dsl.runs.RunError` when the directory cannot be used (busy, a write failed)."""
    from asap_dsl.backends.rl.config import ConfigError, resolve_config
    from asap_dsl.backends.rl.training import train
    from asap_dsl.program import load
    from asap_dsl.runs import RunBusy, RunError, RunWriteError

    t0 = time.perf_counter()
    prog = load(job.spec_file)
    kw = dict(algo=job.algo, engine=job.engine, steps=job.steps, n_envs=job.n_envs, seed=job.seed,
              settings=job.settings)
    try:
        cfg = resolve_config(prog, job.task, **kw)
    except ConfigError as err:
        return TrialOutcome("failed", error=str(err))
    watch = _Watch(report, cfg.validate_every, deadline)
    out = Path(job.run_dir)
    common = dict(out=out, evaluate=False, progress=watch, callbacks=[_stopper(watch)], **kw)
    result = None
    try:
        if (out / "run.json").is_file():
            for steps, score in _past_curve(out):  # the validations before the interruption, told again
                watch.seen(steps, score)
            try:
                result = train(prog, job.task, resume=True, **common)
            except (RunBusy, RunWriteError):
                raise
            except RunError:  # no checkpoint, damaged, another spec: this trial's run starts again
                watch = _Watch(report, cfg.validate_every, deadline)
                common.update(progress=watch, callbacks=[_stopper(watch)])
                result = train(prog, job.task, force=True, **common)
        else:
            result = train(prog, job.task, **common)
    except ConfigError as err:  # the library refused this combination
        return TrialOutcome("failed", error=str(err), seconds=time.perf_counter() - t0)
    score = float(result.best["score"]) if result.best else None
    if watch.best > float("-inf"):
        score = max(score if score is not None else watch.best, watch.best)
    state = ("interrupted" if result.interrupted else "pruned" if watch.pruned
             else "cut" if watch.cut and result.steps < cfg.steps else "complete")
    return TrialOutcome(state, score, int(result.steps), time.perf_counter() - t0, curve=watch.curve)


def job_for(setup: Any, settings: dict, run_dir: Path) -> TrialJob:
    """The job of a trial of ``setup`` (a :class:`~.study.TuneSetup`)."""
    return TrialJob(setup.spec_file, setup.task, setup.algo, setup.engine, setup.steps, setup.n_envs, setup.seed,
                    dict(settings), str(Path(run_dir).resolve()))  # absolute: a Ray worker runs elsewhere
