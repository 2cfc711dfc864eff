"""A sweep of training runs (``asapc compare``): plan them, find the ones that exist, train the
missing ones in parallel (worker processes, or tasks on a Ray cluster: :mod:`.cluster`), and
gather their results.

Idempotent and resumable: every run lives in its own directory under ``<out>/runs``, named after
its spec, task, algorithm, reward and seed plus a short hash of its spec and configuration. A
finished run is read back, never retrained; an interrupted or killed one is resumed from its
checkpoint; a missing one is trained; a damaged one is trained again. Each run is trained under
its exclusive lock, so a run that another process holds is never touched (the job fails, saying
which process holds it).

Worker processes die with the sweep (``PR_SET_PDEATHSIG`` and a parent-PID watch): ``kill -9``
of ``compare`` leaves no training behind, and loses at most each run's steps since its last
checkpoint. Ctrl-C or SIGTERM stop the sweep: running trainings checkpoint, and the same command
continues later.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from asap_dsl.processes import Interrupts
from asap_dsl.runs import RunBusy, RunDir, RunError, default_run_name, spec_hash
from asap_dsl.runsummary import is_summary

__all__ = ["Job", "JobResult", "SweepInterrupted", "execute", "job_config", "job_dir", "load_result", "plan",
           "run_job"]


@dataclass(frozen=True)
class Job:
    """One training run of a sweep (``spec``: the file's absolute path)."""

    spec: str
    task: str
    algo: str
    reward: str
    seed: int
    preset: str = "default"
    steps: Optional[int] = None
    engine: Optional[str] = None  # None: the preset's
    imitation: Optional[float] = None  # the actor's imitation of the oracle's paths (None: the preset's)
    search_iterations: Optional[int] = None  # the policy search after the learner (None: the preset's)

    def label(self) -> str:
        return f"{Path(self.spec).stem} {self.task} {self.algo} {self.reward} s{self.seed}"

    def training(self) -> str:
        """The preset, and what the sweep set apart from it (the report's runs table)."""
        set_ = [f"{name} {value:g}" for name, value in (("imitation", self.imitation),
                                                        ("search iterations", self.search_iterations))
                if value is not None]
        return self.preset + (f" ({', '.join(set_)})" if set_ else "")


def plan(specs: Sequence[str], tasks: Optional[Sequence[str]], rewards: Sequence[str], algos: Sequence[str],
         seeds: int, preset: str = "default", steps: Optional[int] = None, engine: Optional[str] = None, *,
         imitation: Optional[float] = None, search_iterations: Optional[int] = None) -> list[Job]:
    """The runs the paper's tables need: every reward with the first algorithm (Table 1), and every
    algorithm with the first reward (Table 2), for every task of every spec and every seed. A spec
    named twice (``a.asap ./a.asap``) is planned once. ``imitation`` and ``search_iterations`` go to
    every run as ``asapc train``'s flags of those names (None: the preset's)."""
    import asap_dsl

    jobs: list[Job] = []
    for spec in dict.fromkeys(str(Path(s).resolve()) for s in specs):
        prog = asap_dsl.load(spec)
        names = list(tasks) if tasks else list(prog.tasks)
        for t in names:
            prog.task(t)  # KeyError with a suggestion
        for t in names:
            pairs = [(r, algos[0]) for r in rewards] + [(rewards[0], a) for a in algos[1:]]
            for reward, algo in pairs:
                for seed in range(seeds):
                    job = Job(spec, t, algo, reward, seed, preset, steps, engine, imitation, search_iterations)
                    if job not in jobs:
                        jobs.append(job)
    return jobs


def job_config(job: Job, prog):
    """The :class:`~asap_dsl.backends.rl.config.TrainConfig` of ``job`` on its program ``prog``;
    raises ``ConfigError`` for a reward or setting the task cannot take (checked before a sweep)."""
    from ..rl.config import resolve_config

    return resolve_config(prog, job.task, algo=job.algo, reward=job.reward, steps=job.steps, seed=job.seed,
                          preset=job.preset, engine=job.engine, imitation=job.imitation,
                          search_iterations=job.search_iterations)


def job_dir(runs_dir: Path, job: Job, prog, cfg) -> Path:
    """``<runs_dir>/<spec>-<task>-<algo>-<reward>-s<seed>-<hash of spec and configuration>``."""
    key = json.dumps({"spec": spec_hash(prog.source), "config": cfg.key}, sort_keys=True, default=str)
    short = hashlib.sha256(key.encode()).hexdigest()[:8]
    return Path(runs_dir).resolve() / f"{default_run_name(job.spec, cfg.task, cfg.algo, cfg.reward, cfg.seed)}-{short}"


@dataclass
class JobResult:
    """What the report needs of a run, read from its directory."""

    job: Job
    run_dir: str
    status: str            # finished | interrupted | failed
    seconds: float = 0.0
    steps: int = 0
    trained_now: bool = False
    error: Optional[str] = None
    note: Optional[str] = None  # what happened on the way (a damaged run trained again)
    resumed: bool = False       # trained now from the checkpoint an interrupted sweep left
    model: bool = True          # False: read back from its summary, without its model (:mod:`asap_dsl.runsummary`)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["job"] = asdict(self.job)
        return d


def _state(run: RunDir) -> str:
    """``missing``, ``finished`` (model and evaluation check out), ``summary`` (finished, its
    model left out: :mod:`asap_dsl.runsummary`; its evaluation checks out), ``resumable`` or
    ``broken`` (a damaged manifest: trained again). Read under the run's shared lock."""
    if not run.path.exists() or (run.path.is_dir() and not any(e != ".lock" for e in os.listdir(run.path))):
        return "missing"
    with run.acquire(exclusive=False):
        try:
            manifest = run.read_manifest()
        except RunError:
            return "broken"
        if manifest["status"] == "finished":
            try:
                summary = is_summary(run, manifest)
                if not summary:
                    run.model_file(manifest)
                run.read_eval(manifest)
                return "summary" if summary else "finished"
            except RunError:
                pass
    return "resumable"


def run_job(job: Job, runs_dir: str, threads: int = 1) -> dict:
    """Train (or resume, or read back) one run; returns :meth:`JobResult.to_dict`, never raises for
    a run that cannot be used (``status`` failed, ``error`` the sentence). Runs in a worker
    process or a Ray task; one torch thread by default so that workers do not contend."""
    import asap_dsl

    path = ""
    try:
        import torch

        from ..rl.training import train

        if threads > 0:
            torch.set_num_threads(threads)
        prog = asap_dsl.load(job.spec)
        cfg = job_config(job, prog)
        path = str(job_dir(Path(runs_dir), job, prog, cfg))
        run = RunDir(path)
        state = _state(run)
        trained, note, resumed = False, None, state == "resumable"
        if state not in ("finished", "summary"):
            kw = dict(algo=job.algo, reward=job.reward, steps=job.steps, seed=job.seed, preset=job.preset,
                      engine=job.engine, imitation=job.imitation, search_iterations=job.search_iterations, out=path)
            try:
                res = train(prog, job.task, resume=state == "resumable", force=state == "broken", **kw)
            except RunBusy:
                raise
            except RunError as err:
                if state != "resumable":
                    raise
                # A run that cannot go on (a damaged checkpoint or model): trained again, and said so.
                note, resumed = f"trained again: {err}", False
                res = train(prog, job.task, force=True, **kw)
            trained = True
            if res.interrupted:
                return JobResult(job, path, "interrupted", res.seconds, res.steps, True, note=note,
                                 resumed=resumed).to_dict()
        with run.acquire(exclusive=False):
            manifest = run.read_manifest()
            run.read_eval(manifest)
        return JobResult(job, path, "finished", float(manifest["seconds"]), int(manifest["steps_done"]), trained,
                         note=note, resumed=trained and resumed, model=state != "summary").to_dict()
    except KeyboardInterrupt:  # stopped before its training began (nothing of it was created)
        return JobResult(job, path, "interrupted").to_dict()
    except (RunError, asap_dsl.SpecError, ValueError, KeyError) as err:
        text = err.report() if isinstance(err, asap_dsl.SpecError) else str(err.args[0] if err.args else err)
        return JobResult(job, path, "failed", error=text).to_dict()
    except Exception as err:  # noqa: BLE001 — a bug of ours: this run fails, not the sweep
        return JobResult(job, path, "failed", error=f"internal error: {type(err).__name__}: {err}").to_dict()


class SweepInterrupted(Exception):
    """Ctrl-C or SIGTERM stopped the sweep; finished runs are kept, running ones checkpointed.
    ``phase``: what was under way (``training``, ``the oracle``, ``the report``, ...)."""

    def __init__(self, done: list[dict], phase: str = "training"):
        super().__init__("interrupted")
        self.done, self.phase = done, phase


def execute(jobs: Sequence[Job], runs_dir: str, workers: int = 1, ray_address: Optional[str] = None,
            on_event: Optional[Callable[[str, Job, Optional[dict]], None]] = None,
            ray_timeout: float = 30.0) -> list[dict]:
    """Run every job (finished ones are only read back) and return their results in job order.

    ``on_event(kind, job, result)`` is told ``start``, ``done``. ``workers`` processes (spawned, one
    torch thread each) run them locally; with ``ray_address`` (or ``"auto"``) they run as tasks on a
    Ray cluster instead (:mod:`.cluster`; ``ray_timeout`` seconds to connect). Jobs that share a run
    directory (the same spec given twice) run once. Raises :class:`SweepInterrupted` after Ctrl-C
    or SIGTERM.
    """
    Path(runs_dir).mkdir(parents=True, exist_ok=True)
    runs_dir = str(Path(runs_dir).resolve())
    tell = on_event or (lambda kind, job, result: None)
    unique, index = _distinct(jobs, runs_dir)
    if ray_address is not None:
        from .cluster import execute_ray

        run = lambda: execute_ray(unique, runs_dir, ray_address, tell, ray_timeout)  # noqa: E731
    else:
        run = lambda: _execute_local(unique, runs_dir, max(1, int(workers)), tell)  # noqa: E731
    try:
        done = run()
    except SweepInterrupted as err:
        err.done = _spread(err.done, unique, jobs, index)
        raise
    return _spread(done, unique, jobs, index)


def _distinct(jobs: Sequence[Job], runs_dir: str) -> tuple[list[Job], list[int]]:
    """The jobs with distinct run directories, and for each job the one that runs for it."""
    import asap_dsl

    progs: dict[str, Any] = {}
    seen: dict[Path, int] = {}
    unique: list[Job] = []
    index = []
    for job in jobs:
        try:
            prog = progs.setdefault(job.spec, asap_dsl.load(job.spec))
            key = job_dir(Path(runs_dir), job, prog, job_config(job, prog))
        except Exception:  # noqa: BLE001 — the worker reports it, as it reports any failed run
            key = Path(f"<{len(unique)}>")
        if key not in seen:
            seen[key] = len(unique)
            unique.append(job)
        index.append(seen[key])
    return unique, index


def _spread(done: list[dict], unique: list[Job], jobs: Sequence[Job], index: list[int]) -> list[dict]:
    """The results of the distinct jobs, one per job again (in job order; a job whose run had no
    result yet, when the sweep was stopped, has none)."""
    key = lambda d: json.dumps(d, sort_keys=True)  # noqa: E731
    by_job = {key(r["job"]): r for r in done}
    out = []
    for job, k in zip(jobs, index):
        r = by_job.get(key(asdict(unique[k])))
        if r is not None:
            out.append({**r, "job": asdict(job)})
    return out


# ------------------------------------------------------------------------------------ local workers
def _worker_main(conn, parent: int, threads: int, core: Optional[int] = None) -> None:
    """A worker process: jobs in, results out, until the pipe closes. It dies with its parent;
    Ctrl-C is the parent's to forward (as SIGTERM), and a SIGTERM before a training has begun
    ends the job as interrupted (each training installs its own handler)."""
    if core is not None:
        # One core per worker: the learner's helper threads (XLA's pool, the compiled step's) stay
        # on it instead of taking the other worker's. Not shown to pay yet: two bare trainings
        # under taskset took 79 s pinned against 90 s free, but through the sweep
        # (benchmarks/sweep_workers.py) free / pinned was 0.84x and 0.98x: noise or worse.
        try:
            os.sched_setaffinity(0, {core})
        except OSError:
            pass
    from asap_dsl.processes import die_with_parent

    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with Interrupts(signals=(signal.SIGTERM,), raise_outside=True):
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError, KeyboardInterrupt):
                return
            if msg is None:
                return
            job, runs_dir = msg
            try:
                res = run_job(job, runs_dir, threads)
            except KeyboardInterrupt:
                res = JobResult(job, "", "interrupted").to_dict()
            try:
                conn.send(res)
            except (OSError, KeyboardInterrupt):
                return


class _Worker:
    def __init__(self, ctx, threads: int, core: Optional[int] = None):
        parent_end, child_end = ctx.Pipe()
        self.conn = parent_end
        self.core = core
        self.process = ctx.Process(target=_worker_main, args=(child_end, os.getpid(), threads, core), daemon=True)
        self.process.start()
        child_end.close()
        self.job: Optional[tuple[int, Job]] = None

    def signal(self, sig: int) -> None:
        try:
            os.kill(self.process.pid, sig)
        except (OSError, TypeError):
            pass

    def close(self, wait: float) -> None:
        try:
            self.conn.send(None)
        except OSError:
            pass
        self.process.join(wait)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(5)
        self.conn.close()


def _free_core(pool: list, workers: int) -> Optional[int]:
    """A core of this process's set that no live worker holds, when each of ``workers`` can have its
    own; None otherwise (then the kernel places them)."""
    try:
        cores = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None
    if workers < 2 or workers > len(cores):
        return None
    held = {w.core for w in pool if w.process.is_alive()}
    return next((c for c in cores if c not in held), None)


def _died(worker: _Worker) -> str:
    code = worker.process.exitcode
    if code is not None and code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = str(-code)
        return f"its worker process was killed ({name}); run the same command again to continue it"
    return f"its worker process ended (exit status {code}); run the same command again to continue it"


def _execute_local(jobs, runs_dir, workers, tell) -> list[dict]:
    import multiprocessing as mp
    from multiprocessing.connection import wait

    ctx = mp.get_context("spawn")  # from the main thread: the parent-death signal follows this thread
    pool: list[_Worker] = []
    results: dict[int, dict] = {}
    queue = list(enumerate(jobs))

    def forward(signum: int) -> None:  # each training checkpoints on SIGTERM
        for w in pool:
            if w.job is not None:
                w.signal(signal.SIGTERM)

    stop = Interrupts(on_signal=forward)
    aborted = False
    with stop:
        try:
            while True:
                while queue and not stop.requested:
                    idle = [w for w in pool if w.job is None and w.process.is_alive()]
                    if not idle and len(pool) < workers:
                        pool.append(_Worker(ctx, 1, _free_core(pool, workers)))
                        idle = [pool[-1]]
                    if not idle:
                        break
                    i, job = queue.pop(0)
                    idle[0].job = (i, job)
                    idle[0].conn.send((job, runs_dir))
                    tell("start", job, None)
                busy = [w for w in pool if w.job is not None]
                if not busy:
                    break
                ready = wait([w.conn for w in busy] + [w.process.sentinel for w in busy], timeout=0.5)
                for w in busy:
                    if w.conn not in ready and w.process.sentinel not in ready:
                        continue
                    i, job = w.job
                    try:
                        res = w.conn.recv() if w.conn.poll() else None
                    except (EOFError, OSError):
                        res = None
                    if res is None:
                        res = JobResult(job, "", "failed", error=_died(w)).to_dict()
                        pool.remove(w)
                    w.job = None
                    results[i] = res
                    tell("done", job, res)
        except KeyboardInterrupt:  # a third signal: abort, losing the steps since each last checkpoint
            aborted = True
            raise
        finally:
            for w in pool:
                if aborted:
                    w.signal(signal.SIGKILL)
                w.close(wait=0 if aborted else 60)
    done = [results[i] for i in sorted(results)]
    if stop.requested or any(r["status"] == "interrupted" for r in done):
        raise SweepInterrupted(done)
    return done


def load_result(res: dict) -> dict:
    """The files of a finished run that a report reads, each checked: the manifest, the
    evaluation (of this run's model), and the curves (``curves_error`` says why they are missing
    when they cannot be read). Raises :class:`RunError` when the run cannot be used."""
    run = RunDir(res["run_dir"])
    out = dict(res)
    with run.acquire(exclusive=False):
        out["manifest"] = run.read_manifest()
        out["evaluation"] = run.read_eval(out["manifest"])
        try:
            out["curves"], out["curves_error"] = run.read_curves(), None
        except RunError as err:
            out["curves"], out["curves_error"] = [], str(err)
    return out
