"""``asapc tune FILE [--task T] [--trials N] [--time-limit S] [--ray ADDRESS] [--out DIR] [--write]``:
flags, the progress lines, the summary and the winning ``train { ... }`` block.

The search is :mod:`asap_dsl.backends.tune` (Optuna, on this machine or through Ray Tune); this
module reads flags, prints and writes the block. Progress goes to standard error (each trial, its
score and the best so far), the block to standard output. Exit status: 0 done (or the time limit
reached: the same command continues), 1 a problem with the spec or the tune directory, 2 a bad
flag, 130 interrupted (the same command continues).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any, Optional, TextIO

from .args import (InputError, UsageError, add_seed, add_task, check_task, path_arg, positive_amount, positive_int,
                   steps_int)
from .compare import ray_address

__all__ = ["TuneProgress", "fill_tune_subparser", "summary_text", "tune_command"]


def fill_tune_subparser(subparsers) -> argparse.ArgumentParser:
    from asap_dsl.backends.rl.engines import ENGINES
    from asap_dsl.backends.rl.presets import ALGORITHMS

    p = subparsers.add_parser("tune", help="search the training hyperparameters of a task (Optuna; on a Ray cluster "
                              "with --ray) and print, or write, the winning train block")
    p.add_argument("file", type=path_arg, metavar="FILE", help="the .asap spec")
    add_task(p, "the task to tune (default: the only task of the file)")
    p.add_argument("--trials", type=positive_int, default=20,
                   help="trials in all, counting those an earlier call finished (default 20)")
    p.add_argument("--time-limit", type=positive_amount("seconds", 1e8), metavar="SECONDS",
                   help="stop after this long (the running trial is continued by the next call)")
    p.add_argument("--steps", type=steps_int, help="environment steps per trial (default: the train block's, "
                   "else the preset's)")
    p.add_argument("--algo", choices=ALGORITHMS, help="the algorithm to tune (default: the train block's, else sac)")
    p.add_argument("--engine", choices=ENGINES, help="what trains: sbx or sb3 (default: the preset's)")
    p.add_argument("--envs", type=positive_int, dest="n_envs", help="environments per trial (default: the block's, "
                   "else the preset's)")
    add_seed(p, None, "the trials' seed and the sampler's (default: the train block's, else 0)")
    p.add_argument("--ray", metavar="ADDRESS", type=ray_address,
                   help="run the trials through Ray Tune: the head's HOST:PORT, ray://HOST:PORT, auto, or local "
                        "(a cluster of this machine)")
    p.add_argument("--ray-timeout", type=positive_amount("seconds"), default=30.0, metavar="SECONDS",
                   help="give up joining the Ray cluster after this long (default 30)")
    p.add_argument("--out", type=path_arg, metavar="DIR", help="the tune directory (default runs/tune-<spec>-<task>-<algo>)")
    p.add_argument("--force", action="store_true", help="replace the tune directory's earlier tuning")
    p.add_argument("--write", action="store_true", help="write the winning block into the task of FILE")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=tune_command)
    return p


def _settings_text(settings: dict) -> str:
    from asap_dsl.backends.tune.block import setting_text

    return ", ".join(setting_text(k, v) for k, v in settings.items()) if settings else "(the task's own settings)"


def _score(x: Optional[float]) -> str:
    return "-" if x is None else f"{x:.3f}"


class TuneProgress:
    """One line per trial on standard error: its settings when it starts, then how it ended, its score
    and the best so far. Trials are counted ``k of N`` from those done before this call."""

    def __init__(self, stream: TextIO, wanted: int, quiet: bool, done: int = 0, best: Optional[float] = None):
        self.stream, self.wanted, self.quiet = stream, wanted, quiet
        self.best = best
        self.next = done
        self.ordinal: dict[int, int] = {}

    def _k(self, number: int) -> int:
        if number not in self.ordinal:
            self.next += 1
            self.ordinal[number] = self.next
        return self.ordinal[number]

    def __call__(self, event: str, data: Any) -> None:
        if self.quiet:
            return
        if event == "baseline":
            line = ("starting point, the task's own train block: " + (f"score {_score(data.score)}" if data.score is not None
                    else f"{data.state}"))
        elif event == "start":
            number, settings, continues = data
            again = f" (continues trial {self.ordinal.get(continues, continues)} from its checkpoint)" if continues else ""
            line = f"trial {self._k(number)} of {self.wanted}{again}: {_settings_text(settings)}"
        elif event == "trial":
            if data.state == "complete" and data.score is not None:
                self.best = data.score if self.best is None else max(self.best, data.score)
            what = {"complete": f"score {_score(data.score)}",
                    "pruned": f"pruned at {data.steps:,} steps (best validation {_score(data.score)})",
                    "failed": f"failed: {data.error}", "cut": f"cut by the time limit at {data.steps:,} steps",
                    "interrupted": f"interrupted at {data.steps:,} steps"}.get(data.state, data.state)
            line = (f"trial {self._k(data.number)} of {self.wanted}: {what} in {data.seconds:.1f} s; "
                    f"best so far {_score(self.best)}")
        else:
            line = str(data)
        print(line, file=self.stream, flush=True)


def summary_text(res) -> str:
    """The lines printed at the end: trials done, pruned and failed, the best against the start, time."""
    s = res.setup
    done = res.done()
    here = [t for t in res.trials if t.session]
    lines = [f"tuned task {s.task} ({s.algo} on {s.engine}, {s.steps:,} steps per trial, {s.n_envs} env(s)): "
             f"{len(done)} of {res.wanted} trials done ({len(here)} in this call, {res.count('pruned')} pruned, "
             f"{res.count('failed')} failed) in {res.seconds:.1f} s"]
    b = res.best
    lines.append("score: the best validation's mean success rate over the tolerances (validation states, seed 7)")
    lines.append(f"starting point (the task's own block): {_score(res.baseline)}; best trial: "
                 + (f"{_score(b.score)} (trial {b.number})" if b else "none completed"))
    if res.stopped == "time":
        lines.append("stopped at the time limit: run the same command again to continue")
    elif res.stopped == "interrupted":
        lines.append("interrupted: run the same command again to continue (the trial continues from its checkpoint)")
    lines.append(f"tune directory: {res.directory}")
    return "\n".join(lines)


def _winning_block(res, prog) -> Optional[dict]:
    """The task's block with the best trial's settings (None when no trial beat it)."""
    from asap_dsl.backends.rl import hyper
    from asap_dsl.backends.tune.block import merged_block

    if not res.improved:
        return None
    block = res.block
    algo = res.setup.algo if block.get("algo", "sac") != res.setup.algo else None
    keep = sorted(hyper.keywords(res.setup.engine, res.setup.algo).all) if algo else None
    return merged_block(block, res.best.settings, algo=algo, keep=keep)


def tune_command(args: argparse.Namespace, out: Optional[TextIO] = None, err: Optional[TextIO] = None) -> int:
    """Tune (or continue tuning) a task, print the summary and the winning block, and with
    ``--write`` put the block into the spec."""
    from asap_dsl.backends.rl.config import ConfigError
    from asap_dsl.backends.tune import BlockError, ClusterError, Tuning, TuneError, format_block, search_ray, write_block
    from asap_dsl.runs import RunError

    out, err = out or sys.stdout, err or sys.stderr
    check_task(args.task)
    try:
        tuning = Tuning.open(args.file, args.task, algo=args.algo, engine=args.engine, steps=args.steps,
                             n_envs=args.n_envs, seed=args.seed, out=args.out, force=args.force)
    except KeyError as e:
        raise UsageError(e.args[0]) from None
    except ConfigError as e:
        raise UsageError(str(e)) from None
    except TuneError as e:
        raise InputError(str(e)) from None
    if args.task is None and len(tuning.prog.tasks) != 1:
        tuning.close()
        raise UsageError(f"{args.file} has tasks {', '.join(tuning.prog.tasks)}: name one with --task")
    records = tuning.records()
    before = sum(r.state in ("complete", "pruned", "failed") for r in records)
    scores = [r.score for r in records if r.state == "complete" and r.score is not None]
    progress = TuneProgress(err, args.trials, args.quiet, before, max(scores) if scores else None)
    try:
        if before and not args.quiet:
            print(f"continuing the tuning in {tuning.directory}: {before} trial(s) done", file=err, flush=True)
        if args.ray is not None:
            res = search_ray(tuning, args.ray, args.trials, args.time_limit, progress, timeout=args.ray_timeout)
        else:
            res = tuning.search(args.trials, args.time_limit, progress)
    except (TuneError, ClusterError) as e:
        raise InputError(str(e)) from None
    except RunError as e:
        raise InputError(str(e)) from None
    finally:
        tuning.close()
    print(summary_text(res), file=err, flush=True)
    block = _winning_block(res, tuning.prog)
    if block is None:
        out.write(f"no trial scored higher than the task's own train block ({_score(res.baseline)}); it stays as it is\n")
    else:
        out.write(format_block(block, indent="") + "\n")
        if args.write:
            try:
                write_block(args.file, res.setup.task, block)
            except BlockError as e:
                raise InputError(str(e)) from None
            out.write(f"written into task {res.setup.task} of {args.file}\n")
    return 130 if res.stopped == "interrupted" else 0

