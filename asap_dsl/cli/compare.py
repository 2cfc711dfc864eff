"""``asapc compare FILE...``: flags, the sweep's live progress, and the summary printed at the end.

The sweep, the paired evaluation and the report are :mod:`asap_dsl.backends.compare`. Exit
status: 0 the report was written, 1 a problem with a spec, 2 a bad flag, 130 interrupted (the
finished runs are kept and running ones checkpointed: the same command continues).
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Optional, TextIO

from .args import (InputError, UsageError, add_episodes, add_learner_phases, add_workers, names_list, natural_int,
                   path_arg, positive_amount, positive_int, steps_int, tolerances_list, workers)

__all__ = ["SweepProgress", "compare_command", "fill_compare_subparser", "ray_address"]


def ray_address(text: str) -> str:
    """argparse type: a Ray cluster's address (checked here: a typo is a usage error, exit 2)."""
    from asap_dsl.backends.compare.cluster import parse_address

    try:
        return parse_address(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def fill_compare_subparser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("compare", help="train what is missing, evaluate every run on the same states and "
                              "write a report (Markdown and HTML) beside the oracle's ceiling")
    p.add_argument("files", type=path_arg, nargs="+", metavar="FILE", help="the .asap specs")
    p.add_argument("--tasks", type=names_list, help="comma-separated tasks (default: every task of each file)")
    p.add_argument("--rewards", type=names_list, default=["asap", "rho", "distance"],
                   help="comma-separated rewards, Table 1 (default asap,rho,distance)")
    p.add_argument("--algos", type=names_list, default=["sac"], help="comma-separated algorithms, Table 2 (default sac)")
    p.add_argument("--table2-tolerances", type=tolerances_list, default=[], metavar="T,...",
                   help="Table 2 also within these steps, beside every tolerance of the spec (the paper's Table 2: "
                        "30 DC motor, 20 bicycle and attitude, 50 swimmer); at most the deadline")
    p.add_argument("--seeds", type=positive_int, default=3, help="seeds per configuration (default 3)")
    p.add_argument("--steps", type=steps_int, help="environment steps per run (default: the preset's)")
    p.add_argument("--preset", default="default", help="default or paper")
    from asap_dsl.backends.rl.engines import ENGINES

    p.add_argument("--engine", choices=ENGINES, help="what trains every run: sbx (JAX) or sb3 (stable-baselines3 on "
                   "torch; default: the preset's engine where it has the algorithm)")
    add_episodes(p, "evaluation states (default 1000)")
    add_workers(p, "training processes")
    p.add_argument("--ray", metavar="ADDRESS", type=ray_address,
                   help="run the trainings on a Ray cluster: the head's HOST:PORT, ray://HOST:PORT, or auto")
    p.add_argument("--ray-timeout", type=positive_amount("seconds"), default=30.0, metavar="SECONDS",
                   help="give up joining the Ray cluster after this long (default 30)")
    p.add_argument("--out", type=path_arg, default="reports/compare", help="the report and its runs (default reports/compare)")
    p.add_argument("--summaries", type=path_arg, metavar="DIR",
                   help="keep each finished run's summary (manifest, spec, evaluation, curves) in DIR and read "
                        "them back before training: a sweep whose runs directory is lost goes on from DIR")
    p.add_argument("--lookahead", type=natural_int, default=0, metavar="N",
                   help="Table 1 also shows the first reward's policies refined on the spec's simulator by a "
                        "look-ahead holding actions up to N steps (as `asapc eval --lookahead N`)")
    add_learner_phases(p)
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=compare_command)
    return p


class SweepProgress:
    """Runs done, running and an ETA from the mean time of the runs trained so far."""

    def __init__(self, total: int, stream: TextIO = sys.stderr):
        self.total, self.stream = total, stream
        self.done = self.running = self.reused = 0
        self.parallel = 1
        self.times: list[float] = []
        self.started: dict = {}
        self.oracle_t0, self.oracle_tenth = time.perf_counter(), 0
        self.t0 = time.perf_counter()
        self.live = stream.isatty()
        self.bar = None
        if self.live:
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(TextColumn("sweep"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                                TimeElapsedColumn(), console=Console(file=stream), refresh_per_second=2)
            self.bar.start()
            self.task = self.bar.add_task("runs", total=total, info="")

    def _info(self) -> str:
        left = self.total - self.done
        eta = ""
        if self.times:
            per = sum(self.times) / len(self.times)
            eta = f", ETA {per * left / self.parallel / 60:.1f} min"
        return f"{self.running} running, {self.reused} reused{eta}"

    def __call__(self, kind: str, job, result: Optional[dict]) -> None:
        if kind == "start":
            self.running += 1
            self.parallel = max(self.parallel, self.running)  # how many run at once (the workers)
            self.started[job] = time.perf_counter()
        else:
            self.running -= 1
            self.done += 1
            if result and result.get("trained_now"):
                self.times.append(time.perf_counter() - self.started.get(job, self.t0))
            elif result and result.get("status") == "finished":
                self.reused += 1
        if self.bar is not None:
            self.bar.update(self.task, completed=self.done, info=self._info())
        elif kind == "done":
            r = result or {}
            status = r.get("status", "?")
            how = status if status != "finished" else (
                "reused" if not r.get("trained_now") else "resumed" if r.get("resumed") else "trained")
            print(f"  [{self.done}/{self.total}] {job.label()}: {how} ({self._info()})", file=self.stream, flush=True)

    def oracle(self, column: str, solved: int, states: int) -> None:
        """The oracle computing a column's minima (not cached): a line when it starts, each tenth
        of the states on a terminal, and when it is done (minutes for a thousand states)."""
        now = time.perf_counter()
        tenth = 10 * solved // max(1, states)
        if solved == 0:
            self.oracle_t0, self.oracle_tenth = now, 0
            text = f"the oracle: {column}: computing the minima of {states:,} states (cached for the next reports)"
        elif solved >= states:
            text = f"the oracle: {column}: {states:,} states in {now - self.oracle_t0:.0f} s"
        elif self.live and tenth > self.oracle_tenth:
            self.oracle_tenth = tenth
            text = f"the oracle: {column}: {solved:,} of {states:,} states"
        else:
            return
        if self.bar is not None:
            self.bar.console.print(text)
        else:
            print(f"  {text}", file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()


def compare_command(args: argparse.Namespace, out: Optional[TextIO] = None, err: Optional[TextIO] = None) -> int:
    """Plan the sweep (every reward and setting checked first), train what is missing, evaluate,
    write the report and print its Table 1. ``out`` and ``err`` (standard output and error by
    default) take the summary and the progress."""
    import asap_dsl
    from asap_dsl.backends.compare.paired import check_lookahead, check_tolerances, compare
    from asap_dsl.backends.compare.report import markdown
    from asap_dsl.backends.compare.sweep import SweepInterrupted, job_config, plan
    from asap_dsl.backends.rl.presets import ALGORITHMS, PRESETS
    from asap_dsl.limits import available_cores
    from asap_dsl.runs import RunError

    out, err = out or sys.stdout, err or sys.stderr
    bad = [a for a in args.algos if a not in ALGORITHMS]
    if bad:
        raise UsageError(f"unknown algorithm '{bad[0]}'; choose from {', '.join(ALGORITHMS)}")
    if args.preset not in PRESETS:
        raise UsageError(f"unknown preset '{args.preset}'; choose {' or '.join(PRESETS)}")
    n_workers = workers(args)
    try:
        jobs = plan(args.files, args.tasks, args.rewards, args.algos, args.seeds, args.preset, args.steps, args.engine,
                    imitation=args.imitation, search_iterations=args.search_iterations)
        progs = {spec: asap_dsl.load(spec) for spec in {j.spec for j in jobs}}
        for j in jobs:  # every reward and setting checked before anything trains
            job_config(j, progs[j.spec])
        check_tolerances(jobs, args.table2_tolerances)
        check_lookahead(jobs, args.lookahead)
    except KeyError as e:  # an unknown task
        raise UsageError(e.args[0]) from None
    except ValueError as e:  # ConfigError: a reward or setting
        raise UsageError(str(e)) from None
    progress = None if args.quiet else SweepProgress(len(jobs), err)
    try:
        try:
            res = compare(args.files, tasks=args.tasks, rewards=args.rewards, algos=args.algos, seeds=args.seeds,
                          steps=args.steps, preset=args.preset, workers=n_workers, ray=args.ray, out=args.out,
                          episodes=args.episodes, on_event=progress, oracle_workers=available_cores(),
                          ray_timeout=args.ray_timeout, engine=args.engine, table2_tolerances=args.table2_tolerances,
                          on_oracle=progress.oracle if progress else None, summaries=args.summaries,
                          lookahead=args.lookahead, imitation=args.imitation,
                          search_iterations=args.search_iterations)
        finally:  # the bar stops before anything else is printed
            if progress:
                progress.close()
    except SweepInterrupted as e:
        err.write(f"interrupted during {e.phase}: {sum(r['status'] == 'finished' for r in e.done)} of {len(jobs)} "
                  "runs finished and kept; running ones were checkpointed. Run the same command again to continue.\n")
        return 130
    except RunError as e:  # --out is a file, or another compare holds it
        raise InputError(str(e)) from None
    except RuntimeError as e:  # Ray missing or unreachable
        raise InputError(str(e)) from None
    md = markdown(res.data)
    table1 = md.split("## Table 1 — rewards", 1)[1].split("\n## ", 1)[0].strip()
    out.write(f"report: {res.markdown} and {res.html} ({len(res.results)} runs, {res.seconds:.0f} s)\n\n")
    out.write("Table 1 — rewards\n\n" + table1 + "\n")
    if res.failed:  # the report stands without them, and says so; the exit status too
        first = res.failed[0]
        raise InputError(f"{len(res.failed)} of {len(res.results)} runs could not be used and are left out of the "
                         f"report (first: {first['run']}: {first['error']})")
    return 0
