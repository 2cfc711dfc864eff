"""``asapc eval RUN [--episodes N] [--tolerances 30,25] [--seed S] [--lookahead N] [--format json]
[--plot [PATH]] [--video FILE]``: the success rates of a trained run beside the oracle's ceiling, with ``--plot`` a
picture of example trajectories in the state space (:mod:`asap_dsl.backends.compare.phase_plots`),
with ``--video`` an MP4 of the first evaluation states (:mod:`asap_dsl.render`).

The numbers come from :func:`asap_dsl.backends.rl.evaluation.evaluate`; this module reads flags
and prints. Exit status: 0 done, 1 a problem with the spec or the run directory, 2 a bad flag
(a tolerance beyond the deadline included).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Optional, TextIO

from ..runfiles import shown
from ..runs import json_safe
from ..sampling import EVAL_SEED
from .args import (InputError, UsageError, add_episodes, add_format, add_seed, add_workers, natural_int, path_arg,
                   tolerances_list, workers)
from .progress import LiveLine, StatesProgress

__all__ = ["eval_command", "fill_eval_subparser"]


def fill_eval_subparser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("eval", help="success rates of a trained run beside the oracle's ceiling")
    p.add_argument("run", type=path_arg, metavar="RUN", help="a run directory written by `asapc train`")
    add_episodes(p, "initial states (default 1000)")
    p.add_argument("--tolerances", type=tolerances_list, help="comma-separated steps (default: the task's)")
    add_seed(p, EVAL_SEED, f"seed of the initial states (default {EVAL_SEED})")
    p.add_argument("--spec", type=path_arg, help="evaluate against this spec file (it must be the one the run was trained on)")
    p.add_argument("--lookahead", type=natural_int, default=0, metavar="N",
                   help="refine the policy on the spec's simulator: candidate actions held for 1, 2, 3, 5, ... "
                        "up to N steps, the policy after them, the soonest reach taken (never later than the "
                        "policy; 8 is a good start; eval.json keeps the policy's own evaluation)")
    p.add_argument("--no-oracle", action="store_true", help="do not compute the oracle's ceiling when it is not cached")
    add_workers(p, "processes for the oracle")
    add_format(p)
    p.add_argument("--states", action="store_true", help="with --format json: every state's steps and end reason")
    p.add_argument("--plot", nargs="?", const="", default=None, metavar="PATH",
                   help="draw example trajectories in the state space beside the oracle's, as a PNG "
                        "(default: RUN/plots/trajectories.png)")
    p.add_argument("--video", type=path_arg, metavar="FILE", default=None,
                   help="write an MP4 of the policy from the first 3 evaluation states (MuJoCo's renderer "
                        "for the swimmer, the state-space picture otherwise)")
    p.set_defaults(func=eval_command)
    return p


class _Refining(LiveLine):
    """The look-ahead's step and the states it has brought in, on one line of a terminal (nothing
    elsewhere): on a long manoeuvre or a black box it runs for minutes."""

    def __init__(self, stream: TextIO, states: int):
        super().__init__(stream)
        self.states = states

    def __call__(self, step: int, deadline: int, reached: int) -> None:
        self.show(f"look-ahead: step {step}/{deadline}, {reached:,}/{self.states:,} states reached")
        if step >= deadline:  # the rollout is over: the line goes before the oracle's (if any)
            self.close()


def eval_command(args: argparse.Namespace, out: Optional[TextIO] = None, err: Optional[TextIO] = None) -> int:
    """Evaluate the run (the oracle's ceiling computed unless cached or ``--no-oracle``) and print
    the table or the JSON on ``out`` (standard output by default); while the oracle computes, its
    progress goes to ``err`` (standard error), as ``asapc oracle``'s does."""
    from asap_dsl.backends.rl.evaluation import evaluate
    from asap_dsl.runs import RunError, RunWriteError

    out, err = out or sys.stdout, err or sys.stderr
    n_workers = workers(args)
    progress = StatesProgress(err, "ceiling", args.episodes)
    refining = _Refining(err, args.episodes)

    def started() -> None:  # a line on any stream (a log too), then the live count on a terminal
        err.write(f"computing the oracle's ceiling on {args.episodes:,} states (not cached; --no-oracle skips it) ...\n")
        err.flush()
        progress.start = time.perf_counter()

    try:
        try:
            ev = evaluate(args.run, episodes=args.episodes, tolerances=args.tolerances, seed=args.seed, spec=args.spec,
                          oracle="cache" if args.no_oracle else "auto", workers=n_workers, progress=progress,
                          started=started, lookahead=args.lookahead, refining=refining)
        finally:
            progress.close()
            refining.close()
    except RunWriteError as e:  # evaluated, but eval.json could not be stored: shown, then said
        if getattr(e, "evaluation", None) is not None:
            out.write(e.evaluation.render() + "\n")
        raise InputError(f"{e} (the evaluation above was not stored)") from None
    except RunError as e:
        raise InputError(str(e)) from None
    except ValueError as e:  # a tolerance beyond the deadline
        raise UsageError(str(e)) from None
    plot, failed = None, None
    if args.plot is not None:
        from asap_dsl.backends.compare.phase_plots import plot_run

        try:
            plot = plot_run(args.run, args.plot or None, episodes=args.episodes, seed=args.seed, spec=args.spec)
        except RunError as e:  # the evaluation is shown all the same, then the plot's sentence
            failed = str(e)
    video = None
    if args.video is not None and failed is None:
        from asap_dsl.render import RenderError, video_run

        try:
            video = video_run(args.run, args.video, episodes=args.episodes, seed=args.seed, spec=args.spec)
        except (RunError, RenderError) as e:  # the evaluation is shown all the same, then why no video
            failed = str(e)
    if args.format == "json":
        data = json_safe(ev.to_dict(per_state=args.states))
        if plot is not None:
            data["plot"] = str(plot)
        if video is not None:
            data["video"] = {"path": str(video[0]), "frames": video[1], "renderer": video[2]}
        out.write(json.dumps(data, indent=2, allow_nan=False) + "\n")
    else:
        out.write(ev.render() + "\n")
        if plot is not None:
            out.write(f"  plot: {shown(plot)}\n")
        if video is not None:
            out.write(f"  video: {shown(video[0])} ({video[1]} frames, {video[2]} renderer)\n")
    if failed is not None:
        what = "no plot was written" if args.plot is not None and plot is None else "no video was written"
        raise InputError(f"{failed} (the evaluation above was computed; {what})")
    return 0
