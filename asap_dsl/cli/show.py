"""``asapc show FILE [--task T] [--format json]``: the compiled specification as a reader checks it.

:func:`show_data` gathers it as plain data (also the JSON output); the text is drawn from that.
Exit status: 0 shown, 1 the spec has errors (the report, or in JSON the diagnostics), 2 a misused
``--task``.
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Optional

from ..diagnostics import SpecError, format_report, printable, shorten, span_text
from ..formatting import number
from ..observation import describe, shown_scaling
from ..program import Program, load
from ..runs import json_safe
from ..stl import ir
from .args import add_format, add_task, check_task, path_arg

__all__ = ["fill_show_subparser", "show_command", "show_data"]


def fill_show_subparser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("show", help="print the compiled specification: variables, regions, tasks, bounds, r_sat")
    p.add_argument("file", type=path_arg, metavar="FILE")
    add_task(p, "show only this task")
    add_format(p)
    p.set_defaults(func=show_command)
    return p


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
        scaling = shown_scaling(sys_, t)  # said only where it is not every entry by the init box
        data["tasks"][name] = {
            "asap": _formula_text(t.asap),
            "avoid": None if t.avoid is None else _formula_text(t.avoid),
            "specification": _formula_text(t.spec),
            "horizon_steps": _steps(ir.horizon(t.spec)),
            "deadline_steps": t.deadline,
            "deadline_seconds": None if sys_.dt is None else t.deadline * sys_.dt,
            "tolerances": list(t.tolerances),
            "episode": list(t.episode),
            "reward": t.reward.text,
            "observe": list(t.observe),
            **({} if scaling is None else {"observation_scaling": scaling}),
            "init": None if t.init_box is None else [[lo, hi] for lo, hi in zip(*t.init_box)],
            "rho_bounds": [lo, hi],
            "rho_scale": t.rho_scale if t.r_sat is None else 1.0,
            "r_sat": t.r_sat_value,
            "r_sat_mode": "auto" if t.r_sat is None else "given",
            "r_sat_bound": (hi * t.rho_scale + t.k_max) if t.r_sat is None else t.r_sat_bound,
            "train": dict(t.train),
        }
    return data


def _scaling_text(t: dict, s: dict) -> str:
    """``  (scaled for training: p by the init box; v by the state space)`` where show says it."""
    sc = t.get("observation_scaling")
    if sc is None:
        return ""
    names = list(sc["entries"])
    how = "scaling = " + sc["mode"] if sc["explicit"] else "the default preset's scaling"
    return f"  ({how}: {describe(names, [sc['entries'][n] for n in names])})"


def _train_text(v) -> str:
    """A training value as a train block writes it."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return v if v.isidentifier() else json.dumps(v)
    if isinstance(v, (int, float)):
        return str(v)  # as show printed them before lists and named values
    if isinstance(v, list):
        return "[" + ", ".join(_train_text(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {_train_text(x)}" for k, x in v.items()) + "}"
    return str(v)


def _steps(x: float):
    """A whole number of steps, or inf (unbounded) as is: one type per field in the JSON."""
    return int(x) if math.isfinite(x) else x


def show_command(args: argparse.Namespace) -> int:
    """Print the program (text or JSON); a spec with errors is reported (exit 1)."""
    check_task(args.task)
    try:
        prog = load(args.file)
    except SpecError as err:
        if args.format != "json":
            raise
        # The same shape as a file that compiles, with the diagnostics inside and no model.
        errors = len(err.errors)
        print(json.dumps({"file": args.file, "errors": errors, "warnings": len(err.diagnostics) - errors,
                          "diagnostics": [d.as_dict() for d in err.diagnostics]}, indent=2))
        return 1
    check_task(args.task, prog)
    data = show_data(prog, args.task)
    if args.format == "json":
        print(json.dumps(json_safe(data), indent=2, allow_nan=False))
        return 0
    s = data["system"]
    out = [f"{prog.file}", "", f"system {s['name']}: {s['dynamics']}" + (f", integrator {s['integrator']}" if s["integrator"] else "")
           + (f", dt = {number(s['dt'])} s" if s["dt"] is not None else ", no dt (times in steps)")]
    if s["constants"]:
        out.append("  constants: " + ", ".join(f"{k} = {number(v)}" for k, v in s["constants"].items()))
    out.append("")
    out += _table([[x["name"], f"[{number(x['space'][0])}, {number(x['space'][1])}]", f"[{number(x['init'][0])}, {number(x['init'][1])}]"]
                   for x in s["states"]], ["state", "state space", "init"])
    if s["actions"]:
        out.append("")
        out += _table([[a["name"], f"[{number(a['bounds'][0])}, {number(a['bounds'][1])}]"] for a in s["actions"]], ["action", "bounds"])
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
                    "  init           box(" + ", ".join(f"{x['name']} in [{number(lo)}, {number(hi)}]"
                                                     for x, (lo, hi) in zip(s["states"], t["init"])) + ")"]),
                f"  horizon        {number(t['horizon_steps'])} steps",
                f"  deadline       {t['deadline_steps']} steps"
                + ("" if t["deadline_seconds"] is None else f" ({number(t['deadline_seconds'])} s)"),
                f"  tolerances     {', '.join(map(str, t['tolerances']))}",
                f"  episode        {t['episode'][0]}..{t['episode'][1]} steps",
                f"  reward         {t['reward']}",
                f"  observe        {', '.join(t['observe'])}" + _scaling_text(t, s),
                f"  rho bounds     [{number(lo)}, {number(hi)}]  (robustness of asap over the state space, interval analysis)"]
        if t["r_sat_mode"] == "auto":
            out.append(f"  r_sat          {number(t['r_sat'])}  (auto: rho scaled by {number(t['rho_scale'])} = 1/(rho_max - rho_min); "
                       f"theorem's bound rho_max' + k_max = {number(t['r_sat_bound'])})")
        else:
            out.append(f"  r_sat          {number(t['r_sat'])}  (given; theorem's bound {number(t['r_sat_bound'])})")
        if t["train"]:
            out.append("  train          " + ", ".join(f"{k} = {_train_text(v)}" for k, v in t["train"].items()))
    if prog.warnings:
        out.append("")
        out.append(format_report(prog.warnings, {prog.file: prog.source}))
    print("\n".join(printable(line) for line in "\n".join(out).split("\n")))  # names may hold ESC bytes
    return 0
