"""A tuning: its directory, its Optuna study, and the search on this machine.

The tune directory (default ``runs/tune-<spec>-<task>-<algo>``)::

    tune.json     what is tuned (spec file and hash, task, algorithm, engine, steps, environments,
                  seed): a later call continues the tuning only if these agree
    study.log     Optuna's journal (JournalFileBackend: appended record by record under a lock, so
                  a kill leaves every finished trial readable)
    start/        the run of the task's own train block: the starting point the trials must beat
    trials/<id>/  one training run per trial's settings (:mod:`.trial`)
    best.json     the winner so far: settings, score, trial, the block (written atomically)
    .lock         one tuner at a time

Resuming: trials that finished (complete, pruned, or failed because the engine refused their
settings) count toward ``--trials`` and are never run again; a trial that was running when the
process died, or was interrupted or cut by the time limit, is asked again with the same settings
and continues its run directory from the last checkpoint. The sampler (TPE, as rl-zoo3's) is
seeded from the tuning's seed and the number of trials so far, so a resumed session does not
repeat the first session's draws. Pruning is Optuna's MedianPruner on the best validation score
so far, as rl-zoo3 prunes on its evaluations: no trial is pruned before three have completed, nor
in the first third of its validations.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

from .space import SpaceContext, finite, sample, settings_id
from .trial import TrialOutcome, job_for, run_trial

__all__ = ["STUDY", "TrialRecord", "continued_from", "TuneError", "TuneResult", "TuneSetup", "Tuning"]

STUDY = "asap-tune"
_FORMAT = 1


class TuneError(RuntimeError):
    """The tuning cannot go on (its directory, another tuning's flags, a missing package): one sentence."""


@dataclass(frozen=True)
class TuneSetup:
    """What a tuning tunes (``tune.json``)."""

    spec_file: str
    spec_hash: str
    task: str
    algo: str
    engine: str
    steps: int
    n_envs: int
    seed: int
    validations: int

    def context(self) -> SpaceContext:
        return SpaceContext(self.algo, self.engine, self.steps, self.n_envs)


@dataclass
class TrialRecord:
    """One trial as the summary and the progress lines tell it."""

    number: int            # 1-based, in the order the study asked them
    state: str             # complete | pruned | failed | cut | interrupted | running
    score: Optional[float]
    settings: dict
    steps: int = 0
    seconds: float = 0.0
    error: Optional[str] = None
    session: bool = True   # run in this call (not read from an earlier one)


@dataclass
class TuneResult:
    """What a call of the tuning did and where it stands."""

    setup: TuneSetup
    directory: Path
    wanted: int
    trials: list[TrialRecord]
    baseline: Optional[float]
    seconds: float
    stopped: Optional[str] = None  # None | "time" | "interrupted"
    block: dict = field(default_factory=dict)   # the task's own train block

    def done(self) -> list[TrialRecord]:
        return [t for t in self.trials if t.state in ("complete", "pruned", "failed")]

    def count(self, state: str) -> int:
        return sum(t.state == state for t in self.trials)

    @property
    def best(self) -> Optional[TrialRecord]:
        """The completed trial with the highest score (the earliest of a tie)."""
        done = [t for t in self.trials if t.state == "complete" and t.score is not None]
        return max(done, key=lambda t: (t.score, -t.number)) if done else None

    @property
    def improved(self) -> bool:
        """The best trial scored higher than the task's own block."""
        b = self.best
        return b is not None and (self.baseline is None or b.score > self.baseline)


# ------------------------------------------------------------------------------------ optuna
def _optuna():
    try:
        import optuna
    except ImportError:
        raise TuneError("asapc tune needs Optuna: pip install 'asap-dsl[tune]'") from None
    import warnings

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    # TPE's multivariate mode (rl-zoo3's choice) is marked experimental: said once per trial otherwise
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    return optuna


def open_storage(directory: Path):
    """The tuning's Optuna storage: a journal file in its directory."""
    optuna = _optuna()
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend, JournalFileOpenLock

    path = str(directory / "study.log")
    return JournalStorage(JournalFileBackend(path, lock_obj=JournalFileOpenLock(path))), optuna


class Tuning:
    """A tune directory opened for one call: locked, its identity checked, its study loaded."""

    def __init__(self, setup: TuneSetup, directory: Path, prog, block: dict):
        self.setup, self.directory, self.prog, self.block = setup, directory, prog, block
        self.storage, self.optuna = open_storage(directory)
        self.study = self.optuna.create_study(study_name=STUDY, storage=self.storage, direction="maximize",
                                              load_if_exists=True)
        self.lock = None
        self.started = time.monotonic()

    # -- opening
    @classmethod
    def open(cls, spec: str, task: Optional[str], *, algo: Optional[str] = None, engine: Optional[str] = None,
             steps: Optional[int] = None, n_envs: Optional[int] = None, seed: Optional[int] = None,
             out: Optional[str] = None, force: bool = False) -> "Tuning":
        """Open (or create) the tune directory of ``task`` of the spec file ``spec``. Raises
        :class:`TuneError`, ``ConfigError`` (a flag's value), ``KeyError`` (an unknown task) or
        ``asap_dsl.SpecError``."""
        from asap_dsl.backends.rl.config import resolve_config
        from asap_dsl.program import load
        from asap_dsl.runs import RunError, atomic_write_json, lock_dir, spec_hash
        from asap_dsl.runfiles import remove_tree

        _optuna()
        prog = load(spec)
        cfg = resolve_config(prog, task, algo=algo, engine=engine, steps=steps, n_envs=n_envs, seed=seed)
        setup = TuneSetup(str(Path(spec).resolve()), spec_hash(prog.source), cfg.task, cfg.algo, cfg.engine,
                          cfg.steps, cfg.n_envs, cfg.seed, max(1, cfg.steps // max(1, cfg.validate_every)))
        directory = Path(out) if out else Path("runs") / f"tune-{Path(spec).stem}-{cfg.task}-{cfg.algo}"
        if directory.exists() and not directory.is_dir():
            raise TuneError(f"{directory} is a file, not a tune directory; choose another --out")
        known = directory / "tune.json"
        if directory.is_dir() and any(directory.iterdir()) and not known.is_file():
            raise TuneError(f"{directory} is a directory that is not a tuning (it has no tune.json); asapc never "
                            "replaces it: choose another --out")
        try:
            directory.mkdir(parents=True, exist_ok=True)
            lock = lock_dir(directory, exclusive=True)
        except RunError as err:
            raise TuneError(str(err)) from None
        except OSError as err:
            raise TuneError(f"cannot create {directory}: {err.strerror or err}") from None
        try:
            if known.is_file() and force:
                for entry in directory.iterdir():
                    if entry.name != ".lock":
                        remove_tree(entry)
            if known.is_file():
                _check_same(known, setup, directory)
            else:
                atomic_write_json(known, {"format": _FORMAT, **asdict(setup)})
            tuning = cls(setup, directory, prog, dict(prog.task(cfg.task).model.train))
        except BaseException:
            lock.release()
            raise
        tuning.lock = lock
        return tuning

    def close(self) -> None:
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    # -- trials
    def records(self, session: frozenset = frozenset()) -> list[TrialRecord]:
        """Every trial of the study as a record (``session``: the numbers run in this call)."""
        TS = self.optuna.trial.TrialState
        out = []
        for t in self.study.get_trials(deepcopy=False):
            if t.state == TS.WAITING:
                continue
            state = t.user_attrs.get("outcome") or {TS.COMPLETE: "complete", TS.PRUNED: "pruned", TS.FAIL: "failed",
                                                    TS.RUNNING: "running"}[t.state]
            score = t.value if t.state == TS.COMPLETE else t.user_attrs.get("score")
            out.append(TrialRecord(t.number + 1, state, score, t.user_attrs.get("settings", {}),
                                   t.user_attrs.get("steps", 0), t.user_attrs.get("seconds", 0.0),
                                   t.user_attrs.get("error"), t.number in session))
        return out

    def done_count(self) -> int:
        return sum(r.state in ("complete", "pruned", "failed") for r in self.records())

    def recover(self) -> int:
        """Trials left running by a process that died are failed (to be continued), and every
        trial to be continued is asked again with its settings; the number of them."""
        TS = self.optuna.trial.TrialState
        trials = self.study.get_trials(deepcopy=False)
        for t in trials:
            if t.state == TS.RUNNING:
                self.storage.set_trial_user_attr(t._trial_id, "outcome", "interrupted")
                self.storage.set_trial_state_values(t._trial_id, TS.FAIL)
        trials = self.study.get_trials(deepcopy=False)
        continued = {t.user_attrs.get("continues") for t in trials}
        again = 0
        for t in trials:
            if t.state == TS.FAIL and t.user_attrs.get("outcome") in ("interrupted", "cut") and t.number not in continued:
                self.study.enqueue_trial(t.params, user_attrs={"continues": t.number})
                again += 1
        return again

    def record(self, trial, outcome: TrialOutcome, settings: dict) -> None:
        """Tell the study how ``trial`` ended (its settings and numbers kept as user attributes)."""
        TS = self.optuna.trial.TrialState
        for k, v in (("settings", settings), ("steps", outcome.steps), ("seconds", round(outcome.seconds, 3)),
                     ("score", outcome.score), ("error", outcome.error)):
            trial.set_user_attr(k, v)
        if outcome.state == "complete" and finite(outcome.score):
            self.study.tell(trial, float(outcome.score))
        elif outcome.state == "complete":  # no validation ran: nothing to rank it by
            trial.set_user_attr("outcome", "failed")
            trial.set_user_attr("error", "no validation")
            self.study.tell(trial, state=TS.FAIL)
        elif outcome.state == "pruned":
            self.study.tell(trial, state=TS.PRUNED)
        else:
            if outcome.state != "failed":
                trial.set_user_attr("outcome", outcome.state)
            self.study.tell(trial, state=TS.FAIL)

    # -- the starting point
    def baseline(self, deadline: Optional[float]) -> TrialOutcome:
        """The task's own block, trained as a trial without pruning (read when it has finished)."""
        return run_trial(job_for(self.setup, {}, self.directory / "start"), None, deadline)

    # -- the search here
    def search(self, trials: int, time_limit: Optional[float], tell: Callable[[str, Any], None]) -> TuneResult:
        """Run trials on this machine until ``trials`` are done or ``time_limit`` seconds have
        passed; ``tell(event, data)`` hears of each (``baseline``, ``trial``)."""
        optuna = self.optuna
        deadline = None if time_limit is None else self.started + time_limit
        session: set[int] = set()
        stopped = None
        self.recover()
        start = self.baseline_done()
        if start is None:
            outcome = self.baseline(deadline)
            tell("baseline", outcome)
            start = outcome.score if outcome.state == "complete" else None
            stopped = {"interrupted": "interrupted", "cut": "time"}.get(outcome.state)
        else:
            tell("baseline", TrialOutcome("complete", start))
        previous = len(self.study.trials)
        sampler = optuna.samplers.TPESampler(n_startup_trials=5, seed=(self.setup.seed * 1_000_003 + previous) % 2**32,
                                             multivariate=True)
        pruner = optuna.pruners.MedianPruner(n_startup_trials=3, n_warmup_steps=max(1, self.setup.validations // 3))
        study = optuna.load_study(study_name=STUDY, storage=self.storage, sampler=sampler, pruner=pruner)
        ctx = self.setup.context()
        while stopped is None and self.done_count() < trials:
            if deadline is not None and time.monotonic() >= deadline:
                stopped = "time"
                break
            trial = study.ask()
            session.add(trial.number)
            outcome, settings = None, {}
            try:
                settings = sample(trial, ctx)
                tell("start", (trial.number + 1, settings, continued_from(trial)))
                outcome = self._reuse(settings) or run_trial(
                    job_for(self.setup, settings, self.directory / "trials" / settings_id(settings)),
                    _reporter(trial), deadline)
            finally:
                self.record(trial, outcome or TrialOutcome("interrupted"), settings)
            tell("trial", self.records(frozenset(session))[-1])
            self.save_best(start)
            if outcome.state in ("interrupted", "cut"):
                stopped = "interrupted" if outcome.state == "interrupted" else "time"
        return self.result(trials, start, stopped, frozenset(session))

    def _reuse(self, settings: dict) -> Optional[TrialOutcome]:
        """A completed trial's outcome when the sampler asks its settings again (not trained twice)."""
        for r in self.records():
            if r.state == "complete" and r.settings == settings:
                return TrialOutcome("complete", r.score, r.steps, 0.0)
        return None

    def baseline_done(self) -> Optional[float]:
        """The starting point's score when its run has finished (all its steps, or ended on the
        plateau rule)."""
        from asap_dsl.runs import RunDir, RunError

        run = RunDir(self.directory / "start")
        try:
            m = run.read_manifest()
        except RunError:
            return None
        best = m.get("best") or {}
        complete = int(m.get("steps_done", 0)) >= self.setup.steps or "plateau_step" in m
        if m.get("status") == "finished" and complete and "score" in best:
            return float(best["score"])
        return None

    def result(self, trials: int, baseline: Optional[float], stopped: Optional[str],
               session: frozenset = frozenset()) -> TuneResult:
        return TuneResult(self.setup, self.directory, trials, self.records(session), baseline,
                          time.monotonic() - self.started, stopped, self.block)

    def save_best(self, baseline: Optional[float]) -> None:
        """``best.json``: the winner so far (written atomically after every trial)."""
        from asap_dsl.runs import atomic_write_json

        res = self.result(0, baseline, None)
        b = res.best
        atomic_write_json(self.directory / "best.json", {
            "trial": b.number if b else None, "score": b.score if b else None, "settings": b.settings if b else {},
            "baseline": baseline, "improved": res.improved})


def continued_from(trial) -> Optional[int]:
    """The (1-based) number of the interrupted trial that ``trial`` continues, if it does."""
    n = trial.user_attrs.get("continues")
    return None if n is None else int(n) + 1


def _reporter(trial) -> Callable[[int, float, int], bool]:
    def report(period: int, value: float, steps: int) -> bool:
        trial.report(value, period)
        return trial.should_prune()

    return report


def _check_same(path: Path, setup: TuneSetup, directory: Path) -> None:
    """A tune directory continues only the tuning it began (one sentence naming what differs)."""
    try:
        stored = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise TuneError(f"{path} cannot be read ({err}); replace the tuning with --force") from None
    differs = [f"{k} {stored.get(k)!r} (now {v!r})" for k, v in asdict(setup).items()
               if k not in ("spec_file", "validations") and stored.get(k) != v]
    if stored.get("spec_hash") != setup.spec_hash:
        what = "the spec has changed since it began (writing a train block changes it too)"
    elif differs:
        what = "it was begun with " + "; ".join(differs)
    else:
        return
    raise TuneError(f"{directory} holds another tuning: {what}; continue it with the flags it began with, start "
                    "another with --out DIR, or replace it with --force")
