"""``asapc oracle FILE [--task T] [--episodes N] [--workers K] [--seed S] [--format json]``: the
minimum steps per initial state and the best success rate any policy could reach.

The numbers come from :mod:`asap_dsl.backends.oracle`; this module reads flags, shows progress
and prints. Exit status: 0 at least one task solved, 1 a spec error or no task solvable, 2 a
misused flag (an unknown or empty ``--task`` included).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Optional, TextIO

from ..formatting import percent, steps_text
from ..sampling import EVAL_SEED
from .args import (InputError, add_episodes, add_format, add_seed, add_task, add_workers, check_task, path_arg,
                   planner_samples, positive_amount, positive_int, workers)
from .progress import StatesProgress

__all__ = ["add_oracle_arguments", "fill_oracle_subparser", "oracle_command", "render_text"]

def fill_oracle_subparser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("oracle", help="minimum steps per initial state (CasADi) and the best success rate "
                              "any policy could reach")
    add_oracle_arguments(p)
    p.set_defaults(func=oracle_command)
    return p


def add_oracle_arguments(p: argparse.ArgumentParser) -> None:
    """The flags of ``asapc oracle``, on any parser."""
    from asap_dsl.backends.oracle import STATE_TIME_LIMIT

    p.add_argument("file", type=path_arg, metavar="FILE", help="the .asap spec (an ode or map system)")
    add_task(p, "the task (default: every task of the file)")
    add_episodes(p, "initial states, the same as `asapc eval` draws (default 1000)")
    add_workers(p, "processes solving chunks of the states")
    add_seed(p, EVAL_SEED, f"seed of the initial states (default {EVAL_SEED}, as `asapc eval`)")
    p.add_argument("--state-time-limit", type=positive_amount("seconds"), default=STATE_TIME_LIMIT, metavar="SECONDS",
                   help=f"search time per initial state before it is reported as timeout (default {STATE_TIME_LIMIT:g})")
    add_format(p)
    p.add_argument("--states", action="store_true",
                   help="with --format json: include every state's x0, steps, status and actions")
    from asap_dsl.backends.oracle.planner import PlannerBudget

    b = PlannerBudget()
    p.add_argument("--planner", action="store_true",
                   help="plan through the simulator (planner (achievable), as on a black box) also for known dynamics")
    p.add_argument("--samples", type=planner_samples, default=b.samples, metavar="N",
                   help=f"the planner's candidate sequences per iteration (default {b.samples})")
    p.add_argument("--iterations", type=positive_int, default=b.iterations, metavar="N",
                   help=f"the planner's iterations per state (default {b.iterations})")


def render_text(report, out: TextIO) -> None:
    """The text report of one task: the ceiling per tolerance, the minimum steps, what failed."""
    d = report.to_dict(with_states=False)
    c = d["status"]
    n = d["episodes"]
    out.write(f"{d['file']}: task {d['task']} (system {d['system']}) — {d.get('bound') or 'oracle (' + d['label'] + ')'}, "
              f"{n} initial states, seed {d['seed']}, deadline {d['deadline']} steps, "
              f"{d['seconds']:.1f} s on {d['workers']} worker(s)\n")
    if "planner" in d:
        _render_planned(d, out)
        return
    if d["label"] == "local":
        out.write("  IPOPT local optima: each minimum is an upper bound on that state's true minimum time\n")
    else:
        out.write("  convex feasibility problems: the minima are exact\n")
    _render_rates(d, "minimum steps", out)
    out.write(f"\n  no way found within the deadline: {d['unreachable_within_deadline']}/{n}"
              f" (infeasible {c['infeasible']}, solver failed {c['solver_failed']}, timeout {c['timeout']}, nan {c['nan']})\n")
    if c["timeout"]:
        out.write(f"  timeout: {c['timeout']} state(s) undecided after their search time (--state-time-limit); "
                  "the ceiling counts them as not reached, so it may be low\n")
    out.write(f"  solver failures: {c['solver_failures']} solves on {c['states_with_solver_failures']} states; "
              f"unverified by replay: {c['unverified']}\n")
    _render_tightened(d, out)


def _render_planned(d: dict, out: TextIO) -> None:
    """The planner's report: its budget, the achievable rates (lower bounds on the ceiling)."""
    b, c, n = d["planner"], d["status"], d["episodes"]
    out.write(f"  budget: {b['samples']} samples x {b['iterations']} iterations per state (at most "
              f"{b['time_limit']:g} s), {b['method']}, a pilot of {b['pilot']}x; {b['rollouts']:,} rollouts\n")
    out.write("  each state's steps are those of a sequence replayed to the goal: upper bounds on its minimum, "
              "so each rate is a lower bound on the ceiling\n")
    _render_rates(d, "achieved steps", out, "achieved")
    out.write(f"\n  no sequence found within the deadline: {d['unreachable_within_deadline']}/{n}"
              f" (not found {c.get('not_found', 0)}, timeout {c['timeout']}, unverified by replay "
              f"{c.get('unverified', 0)}, nan {c['nan']})\n")
    _render_tightened(d, out)


def _render_tightened(d: dict, out: TextIO) -> None:
    t = d.get("tightened")
    if t and t["from"]:
        out.write(f"  tightened with the solutions of {', '.join(t['from'])} (replayed under this task): "
                  f"{t['improved_states']} states improved\n")


def _render_rates(d: dict, what: str, out: TextIO, column: str = "ceiling") -> None:
    """The rate per tolerance with its interval, and the distribution of the steps."""
    out.write(f"\n  tolerance  {column:<8}  95% CI            states\n")
    for row in d["ceiling"]:
        lo, hi = row["ci95"]
        out.write(f"  {row['tolerance']:>9}  {percent(row['rate'], 5)}  [{percent(lo, 5)}, {percent(hi, 5)}]  "
                  f"{row['count']:>5}/{row['states']}\n")
    dist = d["distribution"]
    out.write(f"\n  {what}: ")
    if dist.get("reached", 0):
        out.write(steps_text(dist) + "\n")
        hist = dist["histogram"]
        top = max(hist.values())
        out.write("  steps  states\n")
        for k in sorted(hist):
            bar = "#" * max(1, round(40 * hist[k] / top))
            out.write(f"  {k:>5}  {hist[k]:>6}  {bar}\n")
    else:
        out.write("no state reaches the goal\n")


def oracle_command(args: argparse.Namespace, out: Optional[TextIO] = None, err: Optional[TextIO] = None) -> int:
    """Run the oracle on every task (or ``--task``). Exit 0 when at least one task was solved,
    1 on a spec error or when no task could be (each unsupported task is named, with the
    operator that stops it), 2 on a misused flag (an unknown or empty ``--task`` included).
    ``out`` and ``err`` (standard output and error by default) take the report and the progress."""
    import asap_dsl
    from asap_dsl.backends.oracle.cache import solve_seeded, store
    from asap_dsl.backends.oracle.planner import PlannerBudget, PlannerUnsupported
    from asap_dsl.backends.oracle.planning import plan_states, shortest_sequences, tighten_planned
    from asap_dsl.stl import ir
    from asap_dsl.backends.oracle.solver import OracleUnsupported, tighten
    from asap_dsl.runfiles import RunWriteError

    out = out or sys.stdout
    err = err or sys.stderr
    n_workers = workers(args)
    check_task(args.task)
    prog = asap_dsl.load(args.file)
    check_task(args.task, prog)
    tasks = [args.task] if args.task else list(prog.tasks)
    if not tasks:
        raise InputError(f"{args.file} has no task")
    reports, skipped = [], []
    planned = args.planner or prog.system.kind == "simulator"
    for t in tasks:
        progress = StatesProgress(err, t, args.episodes, "planner" if planned else "oracle")
        try:
            if planned:  # a black box, or --planner: an achievable bound through the simulator
                budget = PlannerBudget(samples=args.samples, iterations=args.iterations)
                asap = ir.to_text(prog.task(t).model.asap)  # the tasks before with this `asap` hand over their plans
                warm = [w for r in reports if ir.to_text(prog.task(r.task).model.asap) == asap
                        for w in shortest_sequences(r.results, budget.exchange)]
                rep = plan_states(prog, t, episodes=args.episodes, seed=args.seed, workers=n_workers, budget=budget,
                                  time_limit=args.state_time_limit, progress=progress, warm=warm)
            else:
                rep = solve_seeded(prog, t, args.seed, args.episodes, n_workers, time_limit=args.state_time_limit,
                                   progress=progress)
        except (OracleUnsupported, PlannerUnsupported) as e:
            skipped.append({"task": t, "reason": str(e)})
            err.write(f"asapc: {'error' if args.task else 'note'}: {args.file}: task {t} is not solved: {e}\n")
            continue
        finally:
            progress.close()
        reports.append(rep)
    if len(reports) > 1:  # tasks sharing `asap`: make their local minima consistent (replay-verified)
        (tighten_planned if planned else tighten)(prog, reports)
    if args.format == "text":
        for i, rep in enumerate(reports):
            if i:
                out.write("\n")
            render_text(rep, out)
    if args.format == "json":  # one shape, with or without --task
        json.dump({"file": args.file, "tasks": [r.to_dict(with_states=args.states, with_actions=args.states)
                                                for r in reports], "skipped": skipped}, out, indent=2)
        out.write("\n")
    for rep in reports:  # `asapc eval` and reports reuse these minima on the same states (stored once shown)
        try:
            store(prog.source, rep)
        except RunWriteError as e:
            err.write(f"asapc: warning: {e}; `asapc eval` and the reports compute them again\n")
    return 0 if reports else 1
