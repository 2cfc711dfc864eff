"""A sweep of training runs (``asapc compare``): plan them, find the ones that exist, train the
missing ones in parallel (worker processes, or tasks on a Ray cluster), and gather their results.

Idempotent and resumable: every run lives in its own directory under ``<out>/runs``, named after
its spec, task, algorithm, reward and seed plus a short hash of its spec and configuration. A
finished run is read back, never retrained; an interrupted one is resumed from its checkpoint; a
missing one is trained. Ctrl-C or SIGTERM stop the sweep: running trainings checkpoint, and the
same command continues later.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import threading
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from asap_dsl.runs import RunDir, RunError, default_run_name, read_json, spec_hash

__all__ = ["Job", "JobResult", "SweepInterrupted", "execute", "job_config", "job_dir", "plan", "run_job"]


@dataclass(frozen=True)
class Job:
    """One training run of a sweep."""

    spec: str
    task: str
    algo: str
    reward: str
    seed: int
    preset: str = "default"
    steps: Optional[int] = None
    engine: Optional[str] = None  # None: the preset's

    def label(self) -> str:
        return f"{Path(self.spec).stem} {self.task} {self.algo} {self.reward} s{self.seed}"


def plan(specs: Sequence[str], tasks: Optional[Sequence[str]], rewards: Sequence[str], algos: Sequence[str],
         seeds: int, preset: str = "default", steps: Optional[int] = None, engine: Optional[str] = None) -> list[Job]:
    """The runs the paper's tables need: every reward with the first algorithm (Table 1), and every
    algorithm with the first reward (Table 2), for every task of every spec and every seed."""
    import asap_dsl

    jobs: list[Job] = []
    for spec in specs:
        prog = asap_dsl.load(spec)
        names = list(tasks) if tasks else list(prog.tasks)
        for t in names:
            prog.task(t)  # KeyError with a suggestion
        for t in names:
            pairs = [(r, algos[0]) for r in rewards] + [(rewards[0], a) for a in algos[1:]]
            for reward, algo in pairs:
                for seed in range(seeds):
                    job = Job(str(spec), t, algo, reward, seed, preset, steps, engine)
                    if job not in jobs:
                        jobs.append(job)
    return jobs


def job_config(job: Job, prog):
    """The :class:`~asap_dsl.backends.rl.config.TrainConfig` of ``job`` on its program ``prog``;
    raises ``ConfigError`` for a reward or setting the task cannot take (checked before a sweep)."""
    from ..rl.config import resolve_config

    return resolve_config(prog, job.task, algo=job.algo, reward=job.reward, steps=job.steps, seed=job.seed,
                          preset=job.preset, engine=job.engine)


def job_dir(runs_dir: Path, job: Job, prog, cfg) -> Path:
    key = json.dumps({"spec": spec_hash(prog.source), "config": cfg.key}, sort_keys=True, default=str)
    short = hashlib.sha256(key.encode()).hexdigest()[:8]
    return Path(runs_dir) / f"{default_run_name(job.spec, cfg.task, cfg.algo, cfg.reward, cfg.seed)}-{short}"


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

    def to_dict(self) -> dict:
        d = asdict(self)
        d["job"] = asdict(self.job)
        return d


def _state(path: Path) -> str:
    run = RunDir(path)
    if not run.exists():
        return "missing"
    try:
        manifest = run.read_manifest()
    except RunError:
        return "broken"
    if manifest.get("status") == "finished" and run.model_path.is_file() and run.eval_path.is_file():
        return "finished"
    return "resumable"


def run_job(job: Job, runs_dir: str, threads: int = 1) -> dict:
    """Train (or resume, or read back) one run; returns :meth:`JobResult.to_dict`. Runs in a worker
    process or a Ray task; one torch thread by default so that workers do not contend."""
    import torch

    import asap_dsl

    from ..rl.training import train

    if threads > 0:
        torch.set_num_threads(threads)
    prog = asap_dsl.load(job.spec)
    cfg = job_config(job, prog)
    path = job_dir(Path(runs_dir), job, prog, cfg)
    state = _state(path)
    trained = False
    if state != "finished":
        try:
            res = train(prog, job.task, algo=job.algo, reward=job.reward, steps=job.steps, seed=job.seed,
                        preset=job.preset, engine=job.engine, out=path, resume=state == "resumable",
                        force=state == "broken")
        except RunError:  # a checkpoint that cannot be resumed: start that run again
            res = train(prog, job.task, algo=job.algo, reward=job.reward, steps=job.steps, seed=job.seed,
                        preset=job.preset, engine=job.engine, out=path, force=True)
        trained = True
        if res.interrupted:
            return JobResult(job, str(path), "interrupted", res.seconds, res.steps, True).to_dict()
    manifest = RunDir(path).read_manifest()
    return JobResult(job, str(path), "finished", float(manifest.get("seconds", 0.0)),
                     int(manifest.get("steps_done", 0)), trained).to_dict()


class SweepInterrupted(Exception):
    """Ctrl-C or SIGTERM stopped the sweep; finished runs are kept, running ones checkpointed."""

    def __init__(self, done: list[dict]):
        super().__init__("interrupted")
        self.done = done


def _init_worker() -> None:
    # Ctrl-C in a terminal reaches the whole process group: the parent forwards a SIGTERM instead,
    # so a worker ignores SIGINT until its training installs its own handler.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def execute(jobs: Sequence[Job], runs_dir: str, workers: int = 1, ray_address: Optional[str] = None,
            on_event: Optional[Callable[[str, Job, Optional[dict]], None]] = None) -> list[dict]:
    """Run every job (finished ones are only read back) and return their results in job order.

    ``on_event(kind, job, result)`` is told ``start``, ``done``. ``workers`` processes (spawned, one
    torch thread each) run them locally; with ``ray_address`` (or ``"auto"``) they run as tasks on a
    Ray cluster instead. Raises :class:`SweepInterrupted` after Ctrl-C or SIGTERM.
    """
    Path(runs_dir).mkdir(parents=True, exist_ok=True)
    tell = on_event or (lambda kind, job, result: None)
    if ray_address is not None:
        return _execute_ray(jobs, runs_dir, ray_address, tell)
    return _execute_local(jobs, runs_dir, max(1, int(workers)), tell)


def _execute_local(jobs, runs_dir, workers, tell) -> list[dict]:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    results: dict[int, dict] = {}
    stop = {"signal": None}
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"), initializer=_init_worker)

    def handle(signum, frame):
        stop["signal"] = signum
        for p in list(getattr(pool, "_processes", {}).values()):  # each training checkpoints on SIGTERM
            try:
                os.kill(p.pid, signal.SIGTERM)
            except OSError:
                pass

    old = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, handle)
    try:
        queue = list(enumerate(jobs))
        running: dict[Any, tuple[int, Job]] = {}
        while queue or running:
            while queue and len(running) < workers and stop["signal"] is None:
                i, job = queue.pop(0)
                running[pool.submit(run_job, job, str(runs_dir))] = (i, job)
                tell("start", job, None)
            if not running:
                break
            finished, _ = wait(list(running), timeout=0.5, return_when=FIRST_COMPLETED)
            for fut in finished:
                i, job = running.pop(fut)
                try:
                    res = fut.result()
                except Exception as err:  # noqa: BLE001 — one broken run does not sink the sweep
                    res = JobResult(job, "", "failed", error=f"{type(err).__name__}: {err}").to_dict()
                results[i] = res
                tell("done", job, res)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        for sig, h in old.items():
            signal.signal(sig, h)
    done = [results[i] for i in sorted(results)]
    if stop["signal"] is not None or any(r["status"] == "interrupted" for r in done):
        raise SweepInterrupted(done)
    return done


def _execute_ray(jobs, runs_dir, address, tell) -> list[dict]:
    try:
        import ray
    except ImportError:
        raise RuntimeError("--ray needs Ray: pip install 'asap-dsl[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=None if address == "local" else address, ignore_reinit_error=True,
                 log_to_driver=False, include_dashboard=False)
    remote = ray.remote(num_cpus=1, max_retries=0)(run_job)
    futures = {}
    for i, job in enumerate(jobs):
        futures[remote.remote(job, str(Path(runs_dir).resolve()))] = (i, job)
        tell("start", job, None)
    results: dict[int, dict] = {}
    pending = list(futures)
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                i, job = futures[ref]
                try:
                    res = ray.get(ref)
                except Exception as err:  # noqa: BLE001
                    res = JobResult(job, "", "failed", error=f"{type(err).__name__}: {err}").to_dict()
                results[i] = res
                tell("done", job, res)
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref)
        raise SweepInterrupted([results[i] for i in sorted(results)]) from None
    return [results[i] for i in sorted(results)]


def load_result(res: dict) -> dict:
    """The files of a finished run that a report reads: manifest, evaluation and curves."""
    run = RunDir(res["run_dir"])
    out = dict(res)
    out["manifest"] = run.read_manifest()
    out["evaluation"] = read_json(run.eval_path, "evaluation")
    curves = []
    if run.curves_path.is_file():
        import csv

        with open(run.curves_path, newline="") as f:
            curves = list(csv.DictReader(f))
    out["curves"] = curves
    return out

