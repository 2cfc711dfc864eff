"""``asapc``: the command line. I/O lives here; everything it reports is computed elsewhere.

Exit status: 0 success, 1 a problem in the user's spec or data, 2 a usage error (bad flags),
70 an internal error (a bug of ours, reported in one line; ``ASAPC_DEBUG=1`` shows the trace).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from typing import Optional, Sequence

from .. import __version__
from ..diagnostics import SHOWN, Diagnostic, SpecError, format_report, printable, shorten, span_text
from ..limits import LIMITS
from ..program import Program, analyse, loads, read_source
from ..runs import json_safe
from ..stl import ir


# ---------------------------------------------------------------------------------------- lint
def _lint_file(path: str) -> tuple[list[Diagnostic], Optional[str], Optional[Program]]:
    try:
        text = read_source(path)
    except SpecError as err:
        return err.diagnostics, err.source, None
    try:
        model, diagnostics = analyse(text, path)
    except SpecError as err:  # syntax errors
        return err.diagnostics, text, None
    prog = Program(model, [d for d in diagnostics if not d.is_error]) if model is not None else None
    return diagnostics, text, prog


def cmd_lint(args: argparse.Namespace) -> int:
    all_diags: list[Diagnostic] = []
    sources: dict[str, Optional[str]] = {}
    skipped: list[dict] = []  # what --deep could not check, and why
    for path in args.files:
        diags, source, prog = _lint_file(path)
        if args.deep and prog is not None:
            deep, why = _deep_checks(prog, args)
            diags = diags + deep
            skipped += [{"file": path, "task": task, "reason": reason} for task, reason in why]
        all_diags += diags
        sources[path] = source
    errors = sum(d.is_error for d in all_diags)
    warnings = len(all_diags) - errors
    if args.format == "json":
        print(json.dumps({"files": args.files, "errors": errors, "warnings": warnings,
                          "diagnostics": [d.as_dict() for d in all_diags],
                          **({"deep_skipped": skipped} if args.deep else {})}, indent=2))
    else:
        if all_diags:
            print(format_report(all_diags, sources, args.max_diagnostics))
        for s in skipped:
            print(printable(f"{s['file']}: --deep did not check task '{s['task']}': {s['reason']}"))
        n = len(args.files)
        print(f"{n} file{'s' if n != 1 else ''} checked: {errors} error{'s' if errors != 1 else ''}, "
              f"{warnings} warning{'s' if warnings != 1 else ''}")
    if errors or (args.strict and warnings):
        return 1
    return 0


def _deep_checks(prog: Program, args: argparse.Namespace) -> tuple[list[Diagnostic], list[tuple[str, str]]]:
    """``lint --deep``: sample initial states and ask the oracle whether the deadline is feasible.
    Returns the diagnostics and the tasks it could not check, each with the reason."""
    from asap_dsl.diagnostics import make

    if prog.system.kind == "simulator":
        why = f"system {prog.system.name} is a black-box simulator: the oracle needs known dynamics (ode or map)"
        return [], [(name, why) for name in prog.tasks]
    from asap_dsl.backends.oracle.solver import deadline_infeasible

    out, skipped = [], []
    for name in prog.tasks:
        task = prog.model.tasks[name]
        try:
            bad = deadline_infeasible(prog, name, samples=args.samples, seed=0, seconds=args.deep_seconds)
        except ValueError as err:  # a goal the oracle cannot express: say so
            skipped.append((name, str(err)))
            continue
        decided = [b for b in bad if b[1] != "timeout"]
        undecided = [b for b in bad if b[1] == "timeout"]
        for group, says in ((decided, "cannot fulfil"), (undecided, "were not shown to fulfil")):
            if not group:
                continue
            state, _, reason = group[0]
            shown = ", ".join(f"{n}={v:.3g}" for n, v in zip(prog.system.state_names, state))
            out.append(make("W208", f"{len(group)} of {args.samples} sampled initial states of task '{name}' {says} "
                            f"`asap` within the deadline of {task.deadline:,} steps, e.g. from {shown} ({reason})",
                            task.clause_spans["deadline"], prog.file,
                            hint="enlarge the deadline or the action bounds, or shrink the init box"))
    return out, skipped


# ---------------------------------------------------------------------------------------- show
def _fmt(x: float) -> str:
    if isinstance(x, float) and math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.6g}"


def _table(rows: list[list[str]], header: list[str]) -> list[str]:
    widths = [max(len(str(r[i])) for r in [header] + rows) for i in range(len(header))]
    line = lambda r: "  " + "  ".join(str(c).ljust(w) for c, w in zip(r, widths)).rstrip()  # noqa: E731
    return [line(header), "  " + "  ".join("-" * w for w in widths)] + [line(r) for r in rows]


def _formula_text(node: ir.Formula) -> str:
    """A formula with the formulas it uses written out, cut in the middle past 400 characters
    (1,000 formulas defined through each other would print megabytes)."""
    return shorten(ir.to_text(node), 400)


def show_data(prog: Program, only_task: Optional[str] = None) -> dict:
    """Everything ``asapc show`` prints, as plain data (also its JSON output)."""
    sys_ = prog.system
    integ = sys_.integrator
    lines = prog.source.splitlines()
    warnings = [d.as_dict() for d in prog.warnings]
    data = {
        "file": prog.file,
        "errors": 0,
        "warnings": len(warnings),
        "diagnostics": warnings,
        "system": {
            "name": sys_.name,
            "dynamics": sys_.kind if sys_.kind != "simulator" else f'simulator "{sys_.simulator}"',
            "integrator": None if sys_.kind != "ode" else (integ.method if integ.method == "exact" else f"{integ.method}(substeps = {integ.substeps})"),
            "dt": sys_.dt,
            "constants": {k: v for k, v in sys_.consts.items() if k != "dt"},  # dt has its own line
            "states": [{"name": s.name, "space": [s.low, s.high], "init": [s.init_low, s.init_high]} for s in sys_.states],
            "actions": [{"name": a.name, "bounds": [a.low, a.high]} for a in sys_.actions],
            "lets": {k: shorten(span_text(lines, e.span), 400) for k, e in sys_.lets.items()},
        },
        "regions": {n: r.describe() for n, r in prog.model.regions.items()},
        "formulas": {n: _formula_text(f.ir) for n, f in prog.model.formulas.items()},
        "tasks": {},
    }
    for name in prog.tasks:
        if only_task is not None and name != only_task:
            continue
        t = prog.model.tasks[name]
        lo, hi = t.rho_bounds
        data["tasks"][name] = {
            "asap": _formula_text(t.asap),
            "avoid": None if t.avoid is None else _formula_text(t.avoid),
            "specification": _formula_text(t.spec),
            "horizon_steps": _steps(ir.horizon(t.spec)),
            "deadline_steps": t.deadline,
            "deadline_seconds": t.deadline * sys_.dt,
            "tolerances": list(t.tolerances),
            "episode": list(t.episode),
            "reward": t.reward.text,
            "observe": list(t.observe),
            "init": None if t.init_box is None else [[lo, hi] for lo, hi in zip(*t.init_box)],
            "rho_bounds": [lo, hi],
            "rho_scale": t.rho_scale if t.r_sat is None else 1.0,
            "r_sat": t.r_sat_value,
            "r_sat_mode": "auto" if t.r_sat is None else "given",
            "r_sat_bound": (hi * t.rho_scale + t.k_max) if t.r_sat is None else t.r_sat_bound,
            "train": dict(t.train),
        }
    return data


def _steps(x: float):
    """A whole number of steps, or inf (unbounded) as is: one type per field in the JSON."""
    return int(x) if math.isfinite(x) else x


def cmd_show(args: argparse.Namespace) -> int:
    if args.task == "":
        raise _UsageError(EMPTY_TASK)
    try:
        prog = _load(args.file)
    except SpecError as err:
        if args.format != "json":
            raise
        # The same shape as a file that compiles, with the diagnostics inside and no model.
        errors = len(err.errors)
        print(json.dumps({"file": args.file, "errors": errors, "warnings": len(err.diagnostics) - errors,
                          "diagnostics": [d.as_dict() for d in err.diagnostics]}, indent=2))
        return 1
    if args.task is not None and args.task not in prog.tasks:
        raise _UsageError(_unknown_task(args.task, prog))
    data = show_data(prog, args.task)
    if args.format == "json":
        print(json.dumps(json_safe(data), indent=2, allow_nan=False))
        return 0
    s = data["system"]
    out = [f"{prog.file}", "", f"system {s['name']}: {s['dynamics']}" + (f", integrator {s['integrator']}" if s["integrator"] else "")
           + f", dt = {_fmt(s['dt'])} s"]
    if s["constants"]:
        out.append("  constants: " + ", ".join(f"{k} = {_fmt(v)}" for k, v in s["constants"].items()))
    out.append("")
    out += _table([[x["name"], f"[{_fmt(x['space'][0])}, {_fmt(x['space'][1])}]", f"[{_fmt(x['init'][0])}, {_fmt(x['init'][1])}]"]
                   for x in s["states"]], ["state", "state space", "init"])
    if s["actions"]:
        out.append("")
        out += _table([[a["name"], f"[{_fmt(a['bounds'][0])}, {_fmt(a['bounds'][1])}]"] for a in s["actions"]], ["action", "bounds"])
    if s["lets"]:
        out += ["", "lets:"] + [f"  {n} = {e}" for n, e in s["lets"].items()]
    if data["regions"]:
        out += ["", "regions:"] + [f"  {n} = {d}" for n, d in data["regions"].items()]
    if data["formulas"]:
        out += ["", "formulas:"] + [f"  {n} = {d}" for n, d in data["formulas"].items()]
    for name, t in data["tasks"].items():
        lo, hi = t["rho_bounds"]
        out += ["", f"task {name}:",
                f"  asap           {t['asap']}",
                f"  avoid          {t['avoid'] or '(none)'}",
                f"  specification  {t['specification']}",
                *([] if t["init"] is None else [
                    "  init           box(" + ", ".join(f"{x['name']} in [{_fmt(lo)}, {_fmt(hi)}]"
                                                     for x, (lo, hi) in zip(s["states"], t["init"])) + ")"]),
                f"  horizon        {_fmt(t['horizon_steps'])} steps",
                f"  deadline       {t['deadline_steps']} steps ({_fmt(t['deadline_seconds'])} s)",
                f"  tolerances     {', '.join(map(str, t['tolerances']))}",
                f"  episode        {t['episode'][0]}..{t['episode'][1]} steps",
                f"  reward         {t['reward']}",
                f"  observe        {', '.join(t['observe'])}",
                f"  rho bounds     [{_fmt(lo)}, {_fmt(hi)}]  (robustness of asap over the state space, interval analysis)"]
        if t["r_sat_mode"] == "auto":
            out.append(f"  r_sat          {_fmt(t['r_sat'])}  (auto: rho scaled by {_fmt(t['rho_scale'])} = 1/(rho_max - rho_min); "
                       f"theorem's bound rho_max' + k_max = {_fmt(t['r_sat_bound'])})")
        else:
            out.append(f"  r_sat          {_fmt(t['r_sat'])}  (given; theorem's bound {_fmt(t['r_sat_bound'])})")
        if t["train"]:
            out.append("  train          " + ", ".join(f"{k} = {v}" for k, v in t["train"].items()))
    if prog.warnings:
        out.append("")
        out.append(format_report(prog.warnings, {prog.file: prog.source}))
    print("\n".join(printable(line) for line in "\n".join(out).split("\n")))  # names may hold ESC bytes
    return 0


class _UsageError(Exception):
    """A flag or argument that is misused, or names something the spec does not have (exit 2,
    ``asapc: error: ...``)."""


EMPTY_TASK = "--task needs a task name (leave it out for every task, or the only one)"


def usage_error(message: str) -> Exception:
    """The exception a subcommand raises for a misused flag: asapc prints it and exits 2."""
    return _UsageError(message)


def _unknown_task(name: str, prog: Program) -> str:
    try:
        prog.task(name)
    except KeyError as err:
        return str(err.args[0])
    return ""  # pragma: no cover - only called for a missing task


def _load(path: str) -> Program:
    return loads(read_source(path), path)


# ---------------------------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="asapc", description="Check, compile and solve .asap specifications of "
                                "control tasks to fulfil as soon as possible.")
    p.add_argument("-V", "--version", action="version", version=f"asapc {__version__}")
    p.add_argument("--max-spec-size", type=positive_int, metavar="MB", default=None,
                   help="read spec files up to this size (default 10 MB)")
    p.add_argument("--max-deadline", type=positive_int, metavar="STEPS", default=None,
                   help=f"accept deadlines (episodes, windows, oracle horizons) up to this many steps "
                   f"(default {LIMITS.deadline_steps:,})")
    p.add_argument("--max-substeps", type=positive_int, metavar="N", default=None,
                   help=f"accept integrators with up to N substeps per step (default {LIMITS.substeps:,})")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    lint = sub.add_parser("lint", help="check spec files and report every problem")
    lint.add_argument("files", nargs="+", metavar="FILE")
    lint.add_argument("--format", choices=("text", "json"), default="text")
    lint.add_argument("--strict", action="store_true", help="warnings fail too (exit 1)")
    lint.add_argument("--deep", action="store_true", help="also sample initial states and check with the oracle "
                      "that the deadline is feasible (ode and map systems)")
    lint.add_argument("--max-diagnostics", type=natural_int, default=SHOWN, metavar="N",
                      help=f"print the first N diagnostics in full and count the rest (default {SHOWN}; 0: all)")
    lint.add_argument("--samples", type=positive_int, default=16, help="initial states sampled by --deep (default 16)")
    lint.add_argument("--deep-seconds", type=positive_amount("seconds"), default=60.0, metavar="SECONDS",
                      help="search time of --deep per task, shared by its samples (default 60)")
    lint.set_defaults(func=cmd_lint)

    show = sub.add_parser("show", help="print the compiled specification: variables, regions, tasks, bounds, r_sat")
    show.add_argument("file", metavar="FILE")
    show.add_argument("--task", help="show only this task")
    show.add_argument("--format", choices=("text", "json"), default="text")
    show.set_defaults(func=cmd_show)

    from asap_dsl.cli import oracle as oracle_cli, train as train_cli

    train = sub.add_parser("train", help="train a policy for a task (stable-baselines3) and evaluate it")
    train_cli.add_train_arguments(train)
    train.set_defaults(func=train_cli.train_command)

    evaluate = sub.add_parser("eval", help="success rates of a trained run beside the oracle's ceiling")
    train_cli.add_eval_arguments(evaluate)
    evaluate.set_defaults(func=train_cli.eval_command)

    from asap_dsl.cli import compare as compare_cli

    compare = sub.add_parser("compare", help="train what is missing, evaluate every run on the same states and "
                             "write a report (Markdown and HTML) beside the oracle's ceiling")
    compare_cli.add_compare_arguments(compare)
    compare.set_defaults(func=compare_cli.compare_command)

    oracle = sub.add_parser("oracle", help="minimum steps per initial state (CasADi) and the best success rate "
                            "any policy could reach")
    oracle_cli.add_oracle_arguments(oracle)
    oracle.set_defaults(func=oracle_cli.oracle_command)
    return p




def available_cores() -> int:
    """The cores this process may run on (the default and the cap of every --workers)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def seed_int(text: str) -> int:
    """argparse type: a seed, 0 .. 2^32 - 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"a seed is between 0 and 2^32 - 1, got {value}")
    return value


def episodes_int(text: str) -> int:
    """argparse type: a number of initial states, 1 .. ``LIMITS.episodes``."""
    value = positive_int(text)
    if value > LIMITS.episodes:
        raise argparse.ArgumentTypeError(f"at most {LIMITS.episodes:,} initial states, got {value:,}")
    return value


def check_workers(workers: int, force: bool) -> None:
    """More processes than cores only slow every one of them down: refused unless forced."""
    cores = available_cores()
    if workers > cores and not force:
        raise _UsageError(f"--workers {workers} is more than the {cores} cores available; "
                          "pass --force-workers to insist")


def positive_amount(unit: str, limit: float = 1e6):
    """argparse type: a positive, finite number of ``unit`` (minutes, seconds), below ``limit``."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {unit}, got '{text}'") from None
        if not 0 < value < limit:
            raise argparse.ArgumentTypeError(f"expected a positive number of {unit} below {limit:g}, got '{text}'")
        return value

    parse.__name__ = unit  # argparse names the type in its messages
    return parse


def natural_int(text: str) -> int:
    """argparse type: a whole number of at least 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected 0 or more, got {value}")
    return value


def positive_int(text: str) -> int:
    """argparse type: a whole number of at least 1, in plain words otherwise."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {value}")
    return value


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.max_spec_size is not None:
        LIMITS.spec_bytes = args.max_spec_size * 1024 * 1024
    if args.max_deadline is not None:
        LIMITS.deadline_steps = args.max_deadline
    if args.max_substeps is not None:
        LIMITS.substeps = args.max_substeps
    try:
        return int(args.func(args) or 0)
    except SpecError as err:
        print(err.report(), file=sys.stderr)
        n = len(err.errors)
        print(f"{n} error{'s' if n != 1 else ''}", file=sys.stderr)
        return 1
    except _UsageError as err:
        parser.exit(2, f"asapc: error: {err}\n")
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except Exception as err:  # a bug of ours: one line, the trace on request
        if os.environ.get("ASAPC_DEBUG"):
            raise
        print(f"asapc: internal error: {type(err).__name__}: {err} (set ASAPC_DEBUG=1 for the trace; please report it)",
              file=sys.stderr)
        return 70
    return 0

