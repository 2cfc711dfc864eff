"""``asapc train`` and ``asapc eval``: flags, the live progress display, and what is printed.

Everything computed here comes from :mod:`.training` and :mod:`.evaluation`; this module only
reads flags, draws progress and prints results. Exit status: 0 done, 1 a problem with the spec or
the run directory, 2 a bad flag or setting, 130 interrupted (a checkpoint was saved).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Optional, TextIO

from asap_dsl.cli import episodes_int, positive_amount, positive_int as _positive_int, seed_int
from asap_dsl.runs import json_safe
from asap_dsl.sampling import EVAL_SEED

__all__ = ["add_eval_arguments", "add_train_arguments", "eval_command", "train_command"]


def _steps(text: str) -> int:
    """Whole steps, also written as 2e5 or 200_000."""
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of steps, got '{text}'") from None
    if not value.is_integer() or value < 1 or value > 1e12:
        raise argparse.ArgumentTypeError(f"expected a whole number of steps between 1 and 1e12, got '{text}'")
    return int(value)


_minutes = positive_amount("minutes")


def _tolerances(text: str) -> list[int]:
    out = []
    for part in text.replace(" ", "").split(","):
        if not part:
            continue
        try:
            v = int(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"tolerances are whole numbers of steps separated by commas, got '{text}'") from None
        if v < 1:
            raise argparse.ArgumentTypeError(f"a tolerance is at least 1 step, got {v}")
        out.append(v)
    if not out:
        raise argparse.ArgumentTypeError("give at least one tolerance, such as 30,25,15")
    return out


def add_train_arguments(p: argparse.ArgumentParser) -> None:
    from asap_dsl.backends.rl.presets import ALGORITHMS, PRESETS

    p.add_argument("file", metavar="FILE", help="the .asap spec")
    p.add_argument("--task", help="the task to train (default: the only task of the file)")
    p.add_argument("--algo", choices=ALGORITHMS, help="the algorithm (default: the task's train block, else sac)")
    p.add_argument("--reward", help="asap | rho | rho(window = D) | distance(...) (default: the task's reward)")
    p.add_argument("--steps", type=_steps, help="environment steps in all (default: train block, else the preset's)")
    p.add_argument("--seed", type=seed_int, help="the run's seed (default: train block, else 0)")
    p.add_argument("--time-limit", type=_minutes, metavar="MINUTES",
                   help="end the run (as finished) after this much training time, whatever the steps")
    p.add_argument("--preset", choices=tuple(PRESETS), help="default (measured fastest here) or paper (as published)")
    p.add_argument("--envs", type=_positive_int, dest="n_envs", help="environments stepped together (default: the preset's)")
    p.add_argument("--out", help="the run directory (default runs/<spec>-<task>-<algo>-<reward>-s<seed>)")
    p.add_argument("--resume", action="store_true", help="continue the run's checkpoint (same steps, buffer, random state)")
    p.add_argument("--force", action="store_true", help="replace an existing run directory")
    p.add_argument("--no-eval", action="store_true", help="skip the final evaluation")
    p.add_argument("--quiet", action="store_true", help="no progress display")


def add_eval_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", metavar="RUN", help="a run directory written by `asapc train`")
    p.add_argument("--episodes", type=episodes_int, default=1000, help="initial states (default 1000)")
    p.add_argument("--tolerances", type=_tolerances, help="comma-separated steps (default: the task's)")
    p.add_argument("--seed", type=seed_int, default=EVAL_SEED, help=f"seed of the initial states (default {EVAL_SEED})")
    p.add_argument("--spec", help="evaluate against this spec file (it must be the one the run was trained on)")
    p.add_argument("--no-oracle", action="store_true", help="do not compute the oracle's ceiling when it is not cached")
    p.add_argument("--workers", type=_positive_int, help="processes for the oracle (default and at most: the cores)")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.add_argument("--states", action="store_true", help="with --format json: every state's steps and end reason")


# ------------------------------------------------------------------------------------ progress
def _pct(x: Optional[float]) -> str:
    return "n/a" if x is None else f"{100 * x:.1f}%"


def validation_text(row: dict, ceiling: Optional[dict]) -> str:
    """``within 30: 94.0% (ceiling 99.2%) · 25: ...`` for the latest validation."""
    parts = []
    for i, (T, v) in enumerate(sorted(row["rates"].items(), key=lambda kv: -int(kv[0]))):
        head = f"within {T}" if i == 0 else f"{T}"
        c = None if ceiling is None else ceiling.get(int(T))
        parts.append(f"{head}: {_pct(v)}" + (f" (ceiling {_pct(c)})" if c is not None else ""))
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
                f"seed {config.seed}, {config.steps:,} steps on {config.n_envs} env(s)")
        if not self.live:
            print(head + (f", resuming at {done:,}" if done else ""), file=self.stream, flush=True)
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
        self.task_id = self.bar.add_task("steps", total=config.steps, completed=done, rate="")
        self.view = Live(Group(self.bar, self.text), console=console, refresh_per_second=4)
        self.view.start()

    def advance(self, done: int) -> None:
        if self.bar is not None:
            el = time.perf_counter() - self.t0
            rate = f"{(done - self.first) / el:,.0f} steps/s" if el > 0 else ""
            self.bar.update(self.task_id, completed=done, rate=rate)

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


# ------------------------------------------------------------------------------------ commands
def _fail(err: TextIO, message: str, code: int) -> int:
    err.write(f"asapc: error: {message}\n")
    return code


def train_command(args: argparse.Namespace, out: Optional[TextIO] = None, err: Optional[TextIO] = None) -> int:
    import asap_dsl
    from asap_dsl.runs import RunError

    from asap_dsl.backends.rl.config import ConfigError
    from asap_dsl.backends.rl.training import train

    from asap_dsl.cli import EMPTY_TASK

    out, err = out or sys.stdout, err or sys.stderr
    if args.task == "":
        return _fail(err, EMPTY_TASK, 2)
    try:
        prog = asap_dsl.load(args.file)
    except asap_dsl.SpecError as e:
        err.write(f"{e.report()}\n")
        return 1
    if args.task is None and len(prog.tasks) != 1:
        return _fail(err, f"{args.file} has tasks {', '.join(prog.tasks) or '(none)'}: name one with --task", 2)
    progress = None if args.quiet else ConsoleProgress(err)
    try:
        result = train(prog, args.task, algo=args.algo, reward=args.reward, steps=args.steps, seed=args.seed,
                       preset=args.preset, n_envs=args.n_envs, out=args.out, resume=args.resume, force=args.force,
                       progress=progress, evaluate=not args.no_eval,
                       time_limit=None if args.time_limit is None else 60.0 * args.time_limit)
    except KeyError as e:
        return _fail(err, e.args[0], 2)
    except ConfigError as e:
        return _fail(err, str(e), 2)
    except RunError as e:
        return _fail(err, str(e), 1)
    if result.interrupted:
        err.write(f"interrupted at step {result.steps:,} of {result.config.steps:,}: checkpoint saved in "
                  f"{result.run_dir}; continue with `asapc train {args.file} --task {result.config.task} "
                  f"--out {result.run_dir} --resume`\n")
        return 130
    best = result.best
    out.write(f"trained {result.steps:,} steps in {result.seconds:.1f} s: {result.run_dir}\n")
    if best:
        out.write(f"best validation (step {best['steps']:,}): {validation_text(best, None)}\n")
    if result.evaluation is not None:
        out.write("\n" + result.evaluation.render() + "\n")
        if not (result.evaluation.oracle or {}).get("bound") and prog.system.kind != "simulator":
            out.write(f"\nthe oracle's ceiling: asapc eval {result.run_dir}\n")
    return 0


def eval_command(args: argparse.Namespace, out: Optional[TextIO] = None, err: Optional[TextIO] = None) -> int:
    import asap_dsl
    from asap_dsl.runs import RunError

    from asap_dsl.backends.rl.evaluation import evaluate

    out, err = out or sys.stdout, err or sys.stderr
    try:
        ev = evaluate(args.run, episodes=args.episodes, tolerances=args.tolerances, seed=args.seed, spec=args.spec,
                      oracle="cache" if args.no_oracle else "auto", workers=args.workers)
    except asap_dsl.SpecError as e:
        err.write(f"{e.report()}\n")
        return 1
    except RunError as e:
        return _fail(err, str(e), 1)
    except ValueError as e:
        return _fail(err, str(e), 2)
    if args.format == "json":
        out.write(json.dumps(json_safe(ev.to_dict(per_state=args.states)), indent=2, allow_nan=False) + "\n")
    else:
        out.write(ev.render() + "\n")
    return 0
