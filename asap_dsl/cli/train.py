"""``asapc train FILE [--task T] [--algo A] [--reward R] [--steps N] ...``: flags, the live progress
display, and what is printed.

Everything computed here comes from :mod:`asap_dsl.backends.rl` (training, and the final
evaluation); this module only reads flags, draws progress and prints results. Exit status: 0
done, 1 a problem with the spec or the run directory, 2 a bad flag or setting, 130 interrupted
(a checkpoint was saved).
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Optional, TextIO

from ..formatting import percent
from ..runfiles import command_line, shown
from .args import (InputError, UsageError, add_learner_phases, add_seed, add_task, check_task, natural_int, path_arg,
                   positive_amount, positive_int, share_float, steps_int)

__all__ = ["ConsoleProgress", "fill_train_subparser", "train_command", "validation_text"]


def fill_train_subparser(subparsers) -> argparse.ArgumentParser:
    from asap_dsl.backends.rl.engines import ENGINES
    from asap_dsl.backends.rl.presets import ALGORITHMS, PRESETS

    p = subparsers.add_parser("train", help="train a policy for a task (stable-baselines3 or sbx) and evaluate it")
    p.add_argument("file", type=path_arg, metavar="FILE", help="the .asap spec")
    add_task(p, "the task to train (default: the only task of the file)")
    p.add_argument("--algo", choices=ALGORITHMS, help="the algorithm (default: the task's train block, else sac)")
    p.add_argument("--reward", help="asap | rho | rho(window = D) | distance(...) (default: the task's reward)")
    p.add_argument("--steps", type=steps_int, help="environment steps in all (default: train block, else the preset's)")
    add_seed(p, None, "the run's seed (default: train block, else 0)")
    p.add_argument("--time-limit", type=positive_amount("minutes"), metavar="MINUTES",
                   help="end the run (as finished) after this much training time, whatever the steps")
    p.add_argument("--preset", choices=tuple(PRESETS), help="default (measured fastest here) or paper (as published)")
    # How the steps are computed: the flags of an engine (environments, the engine) go here
    # and reach train() through _engine_options.
    p.add_argument("--envs", type=positive_int, dest="n_envs", help="environments stepped together (default: the preset's)")
    p.add_argument("--engine", choices=ENGINES, help="what trains: sbx (JAX) or sb3 (stable-baselines3 on torch; "
                   "default: the preset's engine where it has the algorithm)")
    p.add_argument("--demonstrations", type=natural_int, metavar="N",
                   help="initial states whose oracle (or, on a black box, planner) action sequences go into the "
                        "replay buffer before learning (SAC, TD3, DDPG; default: the preset's, once validation "
                        "stalls or finds nothing; 0: none)")
    add_learner_phases(p)
    p.add_argument("--failed-starts", type=share_float, metavar="P",
                   help="the share of new training episodes that start where an earlier one did not reach "
                        "(default: the preset's, 0.5; 0: none)")
    p.add_argument("--out", type=path_arg, help="the run directory (default runs/<spec>-<task>-<algo>-<reward>-s<seed>)")
    p.add_argument("--resume", action="store_true", help="continue the run's checkpoint (same steps, buffer, random state)")
    p.add_argument("--force", action="store_true", help="replace an existing run directory")
    p.add_argument("--no-eval", action="store_true", help="skip the final evaluation")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=train_command)
    return p


# ------------------------------------------------------------------------------------ progress
def validation_text(row: dict, ceiling: Optional[dict]) -> str:
    """``within 30: 94.0% (ceiling 99.2%) · 25: ...`` for the latest validation."""
    parts = []
    for i, (T, v) in enumerate(sorted(row["rates"].items(), key=lambda kv: -int(kv[0]))):
        head = f"within {T}" if i == 0 else f"{T}"
        c = None if ceiling is None else ceiling.get(int(T))
        parts.append(f"{head}: {percent(v)}" + (f" (ceiling {percent(c)})" if c is not None else ""))
    return " · ".join(parts)


class ConsoleProgress:
    """A rich progress bar on a terminal; one plain line per validation elsewhere (logs, CI)."""

    def __init__(self, stream: TextIO = sys.stderr, label: str = "training"):
        self.stream, self.label = stream, label
        self.live = stream.isatty()
        self.bar = None
        self.ceiling: Optional[dict] = None
        self.t0 = self.printed = time.perf_counter()
        self.first = self.total = 0

    def start(self, config, done: int, ceiling: Optional[dict]) -> None:
        self.total, self.ceiling, self.first = config.steps, ceiling, done
        self.t0 = time.perf_counter()
        head = (f"{self.label}: task {config.task}, {config.algo}, {config.reward} reward, {config.preset} preset, "
                f"seed {config.seed}, {config.steps:,} steps on {config.n_envs} env(s), {config.engine} engine")
        # Other states than validation's: a guide, not the validation's own limit.
        whose = ("  the ceiling beside each validation is the oracle's on the evaluation states, not on validation's"
                 if ceiling is not None else None)
        if not self.live:
            print(head + (f", resuming at {done:,}" if done else ""), file=self.stream, flush=True)
            if whose:
                print(whose, file=self.stream, flush=True)
            return
        from rich.console import Console, Group
        from rich.live import Live
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
        from rich.text import Text

        console = Console(file=self.stream)
        # Two lines: the bar, then the latest validation (too wide to share the bar's line).
        self.bar = Progress(TextColumn("steps"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[rate]}"),
                            TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), console=console)
        self.text = Text("  validation: pending", overflow="fold")
        console.print(head)
        if whose:
            console.print(whose)
        self.task_id = self.bar.add_task("steps", total=config.steps, completed=done, rate="")
        self.view = Live(Group(self.bar, self.text), console=console, refresh_per_second=4)
        self.view.start()

    def advance(self, done: int) -> None:
        if self.bar is not None:
            el = time.perf_counter() - self.t0
            rate = f"{(done - self.first) / el:,.0f} steps/s" if el > 0 else ""
            self.bar.update(self.task_id, completed=done, rate=rate)

    def note(self, line: str) -> None:
        """A line before training starts (the demonstrations)."""
        print(line, file=self.stream, flush=True)

    def validated(self, row: dict) -> None:
        text = f"validation at {row['steps']:,} steps: {validation_text(row, self.ceiling)}" + ("  [best]" if row["best"] else "")
        if self.bar is not None:
            self.text.plain = "  " + text
        else:  # a log line at most every 10 s, and for every new best
            now = time.perf_counter()
            if row["best"] or now - self.printed >= 10.0 or row["steps"] >= self.total:
                self.printed = now
                speed = (row["steps"] - self.first) / (now - self.t0) if now > self.t0 else 0.0
                print(f"  {row['seconds']:7.1f} s  {speed:8,.0f} steps/s  {text}", file=self.stream, flush=True)

    def finish(self) -> None:
        if self.bar is not None:
            self.view.stop()
            self.bar = None


# ------------------------------------------------------------------------------------- command
def _engine_options(args: argparse.Namespace) -> dict:
    """The keywords of :func:`~asap_dsl.backends.rl.training.train` that say how the steps are
    computed (not what is trained)."""
    return {"n_envs": args.n_envs, "engine": args.engine}


def train_command(args: argparse.Namespace, out: Optional[TextIO] = None, err: Optional[TextIO] = None) -> int:
    """Train (or resume) a run, then print where it is, its best validation and its evaluation.
    ``out`` and ``err`` (standard output and error by default) take the results and the progress."""
    import asap_dsl
    from asap_dsl.backends.rl.config import ConfigError
    from asap_dsl.backends.rl.training import train
    from asap_dsl.runs import RunError

    out, err = out or sys.stdout, err or sys.stderr
    check_task(args.task)
    prog = asap_dsl.load(args.file)
    if args.task is None and len(prog.tasks) != 1:
        raise UsageError(f"{args.file} has tasks {', '.join(prog.tasks) or '(none)'}: name one with --task")
    progress = None if args.quiet else ConsoleProgress(err)
    try:
        result = train(prog, args.task, algo=args.algo, reward=args.reward, steps=args.steps, seed=args.seed,
                       preset=args.preset, out=args.out, resume=args.resume, force=args.force,
                       progress=progress, evaluate=not args.no_eval,
                       time_limit=None if args.time_limit is None else 60.0 * args.time_limit,
                       demonstrations=args.demonstrations, failed_starts=args.failed_starts,
                       imitation=args.imitation, search_iterations=args.search_iterations,
                       **_engine_options(args))
    except KeyError as e:  # an unknown task
        raise UsageError(e.args[0]) from None
    except ConfigError as e:
        raise UsageError(str(e)) from None
    except RunError as e:
        raise InputError(str(e)) from None
    if result.interrupted:
        err.write(f"interrupted at step {result.steps:,} of {result.config.steps:,}: checkpoint saved in "
                  f"{shown(result.run_dir)}; continue with `{result.resume_command}`\n")
        return 130
    best = result.best
    out.write(f"trained {result.steps:,} steps in {result.seconds:.1f} s: {shown(result.run_dir)}\n")
    if best:
        searched = f", policy search iteration {best['search_iteration']:,}" if "search_iteration" in best else ""
        if best.get("action_gain", 1.0) != 1.0:
            searched += f", actions with gain {best['action_gain']:g}"
        out.write(f"best validation (step {best['steps']:,}{searched}): {validation_text(best, None)}\n")
    if result.never_succeeded:
        out.write(f"no validation succeeded ({len(result.curves)} on {result.config.validation_episodes:,} states, 0% at "
                  f"every tolerance): model.zip is the latest policy (step {best['steps']:,}); more steps, or the "
                  "oracle's sequences in the replay buffer (--demonstrations 8; measured: gSDE alone did not "
                  "help, docs/training.md), may find the goal\n")
    if result.evaluation is not None:
        out.write("\n" + result.evaluation.render() + "\n")
        if not (result.evaluation.oracle or {}).get("bound") and prog.system.kind != "simulator":
            out.write(f"\nthe oracle's ceiling: {command_line(['asapc', 'eval', str(result.run_dir)])}\n")
    return 0
