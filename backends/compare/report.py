"""The comparison report: the paper's tables beside the physical limit, as Markdown and as one
self-contained HTML file (inline CSS, plots embedded as data URIs: it makes no request).

Input is plain data gathered by the sweep (:mod:`.compare`): per run its job, manifest, final
evaluation and training curves; per task the oracle's ceiling and the non-RL methods (greedy,
oracle replay). Nothing here trains, evaluates or reads run directories.

Cells are the mean ± standard deviation over seeds of a method's success rate, with the 95%
Wilson interval of the successes pooled over seeds (seeds × episodes trials); the best method of
each column (the ceiling aside) is in bold where there is one: not where every method ties (at 0
or anywhere else) or only one method has a cell.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from asap_dsl.formatting import percent
from asap_dsl.runs import atomic_write, atomic_write_json, json_safe
from asap_dsl.stats import mean_spread, rate, wilson_interval

__all__ = ["Column", "Method", "ReportData", "markdown", "html_page", "summary", "write"]

REWARD_NAMES = {"asap": "ASAP-Phi", "rho": "ρ reward", "distance": "d reward"}


@dataclass
class Column:
    """One (spec, task) pair: a column of every table."""

    spec: str
    task: str
    tolerances: list[int]
    deadline: int
    ceiling: Optional[dict] = None     # {T: {"rate", "ci95", ...}}, or None (black box / unsupported)
    bound: Optional[str] = None        # "oracle (exact)" / "oracle (local)"
    oracle_steps: Optional[list] = None
    label: Optional[str] = None        # the spec's name in the report (default: its file name without .asap)
    black_box: bool = False            # a simulator: its ceiling is the planner's, when asapc oracle cached it

    @property
    def name(self) -> str:
        short = {"reach": "R", "reach_avoid": "R&A"}.get(self.task, self.task)
        return f"{self.label or Path(self.spec).stem} {short}"


def evaluation_row(ev: dict, T: int) -> Optional[dict]:
    """An evaluation's ``{"count", "states", "rate", ...}`` within ``T`` steps: its row where it was
    judged at ``T``, else counted from its states' steps to reach (any ``T`` up to the deadline:
    a tolerance the spec does not name, such as the paper's Table 2's); None without either."""
    for row in ev.get("rows") or []:
        if row["tolerance"] == T:
            return row
    steps = (ev.get("per_state") or {}).get("t_reach")
    if steps is None:
        return None
    return rate(np.array([x is not None and x <= T for x in steps], dtype=bool))


@dataclass
class Method:
    """A row: one method (reward × algorithm, or a non-RL controller) and its evaluations per
    column, one per seed."""

    key: str
    label: str
    kind: str                                  # "rl" | "lookahead" | "greedy" | "oracle"
    evaluations: dict[str, list[dict]] = field(default_factory=dict)  # column name -> evaluation dicts

    def cell(self, col: str, T: int) -> Optional[dict]:
        evs = self.evaluations.get(col) or []
        rates, k, n = [], 0, 0
        for ev in evs:
            row = evaluation_row(ev, T)
            if row is not None and row["rate"] is not None:
                rates.append(row["rate"])
                k += row["count"]
                n += row["states"]
        if not rates:
            return None
        ms = mean_spread(rates)
        return {"mean": ms["mean"], "std": ms["std"], "seeds": ms["n"], "ci95": list(wilson_interval(k, n))}

    def gap(self, col: str) -> Optional[dict]:
        gaps = [ev["gap"]["gap"] for ev in self.evaluations.get(col) or [] if ev.get("gap") and ev["gap"].get("gap") is not None]
        if not gaps:
            return None
        return mean_spread(gaps)


@dataclass
class ReportData:
    title: str
    columns: list[Column]
    table1: list[Method]      # rewards (first algorithm) + greedy
    table2: list[Method]      # algorithms (first reward)
    runs: list[dict]          # what was run: label, spec hash, seed, preset, phases, steps, seconds, status
    # Table 2 also within these (the paper's Table 2 tolerance where the spec does not name it).
    table2_tolerances: list[int] = field(default_factory=list)
    plots: dict[str, bytes] = field(default_factory=dict)  # name -> PNG
    notes: list[str] = field(default_factory=list)
    versions: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0


#: Rows never in bold: the oracle's replay, and the policies refined at run time by the look-ahead
#: (what the simulator adds to a policy, not what a reward or algorithm trained).
UNRANKED = ("oracle", "lookahead")


def lookahead_caption(data: ReportData) -> Optional[str]:
    """What Table 1's look-ahead row is, where it has one."""
    if not any(m.kind == "lookahead" for m in data.table1):
        return None
    return ("The look-ahead row is the first row's policies refined on the spec's simulator at run time "
            "(`asapc eval --lookahead N`: candidate actions held for up to N steps, the policy after them, the "
            "soonest reach taken; never later than the policy): what the simulator adds to a trained policy, "
            "not a trained policy, so never in bold.")


def _pct(x: Optional[float]) -> str:
    return percent(x, sign="")  # the table's header says %


def _cell_text(c: Optional[dict], bold: bool, md: bool) -> str:
    if c is None:
        return "—"
    core = f"{_pct(c['mean'])} ± {_pct(c['std'])}" if c["seeds"] > 1 else f"{_pct(c['mean'])}"
    if bold:
        core = f"**{core}**" if md else f"<b>{core}</b>"
    return f"{core} [{_pct(c['ci95'][0])}, {_pct(c['ci95'][1])}]"


def _best(methods: list[Method], col: str, T: int) -> Optional[float]:
    """The best mean of a column at ``T`` (the oracle's replay aside), or None where there is no
    real best: a single method, every method tied, or the best at 0 (bold would mark nothing)."""
    vals = [c["mean"] for m in methods if m.kind not in UNRANKED for c in [m.cell(col, T)] if c is not None]
    if len(vals) < 2 or max(vals) <= 0 or max(vals) - min(vals) <= 1e-12:
        return None
    return max(vals)


def _tolerances(columns: list[Column], extra: Sequence[int] = ()) -> list[int]:
    return sorted({T for c in columns for T in c.tolerances} | set(extra), reverse=True)


def ceiling_label(columns: list[Column]) -> str:
    """The ceiling row's name: ``oracle ceiling`` for known dynamics, ``planner (achievable)`` where
    every ceiling is the planner's (a black box: a lower bound on the true ceiling), ``ceiling``
    for a mix (each planner cell then says so)."""
    bounds = {_planned(c) for c in columns if c.ceiling or c.black_box}
    if bounds == {True}:
        return PLANNER
    return "ceiling" if bounds == {True, False} else "oracle ceiling"


PLANNER = "planner (achievable)"


def _planned(col: Column) -> bool:
    return col.black_box or reference(col.bound) == "planner"


def table_rows(methods: list[Method], columns: list[Column], md: bool, extra: Sequence[int] = ()) -> list[list[str]]:
    """Rows of a Table-1-style block: for each tolerance (the spec's, and ``extra`` up to each
    column's deadline), each method, then the ceiling."""
    rows = []
    label = ceiling_label(columns)
    for T in _tolerances(columns, extra):
        shown = {col.name: T in col.tolerances or (T in extra and T <= col.deadline) for col in columns}
        for m in methods:
            row = [str(T), m.label]
            for col in columns:
                c = m.cell(col.name, T) if shown[col.name] else None
                best = _best(methods, col.name, T)
                row.append(_cell_text(c, c is not None and best is not None and c["mean"] >= best - 1e-12 and m.kind not in UNRANKED, md))
            rows.append(row)
        ceil = [str(T), label]
        for col in columns:
            r = (col.ceiling or {}).get(T) if shown[col.name] else None
            mark = f" {col.bound}" if label == "ceiling" and _planned(col) else ""  # achievable: a lower bound
            ceil.append("—" if r is None else f"{_pct(r['rate'])} [{_pct(r['ci95'][0])}, {_pct(r['ci95'][1])}]" + mark)
        rows.append(ceil)
    return rows


def table2_caption(data: "ReportData") -> Optional[str]:
    """What Table 2's extra tolerances are, where some column's spec does not name them."""
    extra = [T for T in sorted(data.table2_tolerances, reverse=True)
             if any(T not in c.tolerances and T <= c.deadline for c in data.columns)]
    if not extra:
        return None
    within = ", ".join(str(T) for T in extra)
    return (f"Within {within} steps (`--table2-tolerances`, beside the spec's own tolerances): counted from each "
            "state's steps to reach, for the runs and the ceiling alike.")


def gap_rows(methods: list[Method], columns: list[Column]) -> list[list[str]]:
    rows = []
    for m in methods:
        row = [m.label]
        for col in columns:
            g = m.gap(col.name)
            row.append("—" if g is None else (f"{g['mean']:.3f}" + (f" ± {g['std']:.3f}" if g["n"] > 1 else "")))
        rows.append(row)
    return rows


def _md_table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _bounds(columns: list[Column]) -> str:
    parts = []
    for c in columns:
        if c.bound:
            parts.append(f"{c.name}: {c.bound}" + (", a lower bound on the true ceiling" if _planned(c) else ""))
        elif c.black_box:
            parts.append(f"{c.name}: none, the planner's achievable steps are not cached for these states (see the notes)")
        else:
            parts.append(f"{c.name}: none, a task the oracle cannot solve")
    return "; ".join(parts)


def reference(bound: Optional[str]) -> str:
    """Whose sequences a ceiling's are: ``planner`` for ``planner (achievable)``, else ``oracle``."""
    return "planner" if (bound or "").startswith("planner") else "oracle"


def references(columns: list[Column]) -> str:
    """``oracle``, ``planner`` or ``oracle or planner``: whose sequences the columns' ceilings are."""
    kinds = sorted({"planner" if _planned(c) else "oracle" for c in columns if c.bound or c.black_box})
    return " or ".join(kinds) if kinds else "oracle"


def plot_titles(columns: list[Column]) -> dict[str, str]:
    who = references(columns)
    return {
        "state_space": f"Example trajectories in the state space: the policy (solid) beside the {who} (dashed)",
        "success_vs_tolerance": "Success rate against tolerance, beside the ceiling",
        "steps_vs_oracle": f"Each state's steps to reach against the {who}'s",
        "trajectories": f"Example trajectories beside the {who}'s (robustness of asap over time)",
        "training_curves": "Training curves: validation success against wall time and steps",
    }


def gap_caption(columns: list[Column]) -> str:
    """What the ASAP gap divides by: the oracle's minimum, or the planner's achievable steps (upper
    bounds on the minimum: under 1.000 a method beat the planner, not the physical limit)."""
    who = references(columns)
    if who == "oracle":
        of, limit = "oracle's minimum", "1.000 is the physical limit"
    elif who == "planner":
        of, limit = ("planner's achievable steps", "1.000 is the planner's pace, an upper bound on the minimum "
                     "(under 1.000: faster than the planner)")
    else:
        of, limit = ("oracle's minimum; for a black box the planner's achievable steps",
                     "1.000 is the physical limit (the planner's pace for a black box, an upper bound on it)")
    return (f"Median over the states both reach of (method's steps) / ({of}); {limit} "
            "(mean ± standard deviation over seeds).")




def markdown(data: ReportData, plot_dir: str = "plots") -> str:
    cols = data.columns
    header = ["within", "method"] + [c.name for c in cols]
    lines = [f"# {data.title}", "",
             "Success rate (%) on the seeded evaluation states (seed 2024): mean ± standard deviation over seeds, "
             "[95% Wilson interval of the pooled successes]; the best per column in bold (none where all tie). Ceiling: " + _bounds(cols) + ".",
             "", "## Table 1 — rewards", "", _md_table(header, table_rows(data.table1, cols, md=True)), ""]
    caption = lookahead_caption(data)
    if caption:
        lines += [caption, ""]
    if data.table2:
        note = table2_caption(data)
        lines += ["## Table 2 — algorithms", ""] + ([note, ""] if note else []) + \
                 [_md_table(header, table_rows(data.table2, cols, md=True, extra=data.table2_tolerances)), ""]
    lines += ["## ASAP gap", "", gap_caption(cols), "",
              _md_table(["method"] + [c.name for c in cols], gap_rows(unique(data.table1 + data.table2), cols)), ""]
    for name, title in plot_titles(cols).items():
        if name in data.plots:
            lines += [f"## {title}", "", f"![{title}]({plot_dir}/{name}.png)", ""]
    lines += ["## What was run", "", _md_table(RUN_COLUMNS, run_rows(data)),
              "", "Package versions: " + ", ".join(f"{k} {v}" for k, v in data.versions.items()) + ".",
              f"Report built in {data.seconds:.1f} s."]
    for n in data.notes:
        lines += ["", f"Note: {n}"]
    return "\n".join(lines) + "\n"


RUN_COLUMNS = ["run", "spec sha256", "seed", "preset", "beyond the learner", "steps", "train s", "status"]


def run_rows(data: ReportData) -> list[list[str]]:
    """The rows of "What was run", in :data:`RUN_COLUMNS` order (a report read back from before
    runs recorded their phases shows none)."""
    return [[r["label"], r["spec_hash"][:12], str(r["seed"]), r["preset"], r.get("phases", ""), f"{r['steps']:,}",
             f"{r['seconds']:.1f}", r["status"]] for r in data.runs]


def unique(methods: list[Method]) -> list[Method]:
    seen, out = set(), []
    for m in methods:
        if m.key not in seen:
            seen.add(m.key)
            out.append(m)
    return out


CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 2em auto; max-width: 75em;
       color: #1f2328; padding: 0 1em; }
h1 { font-size: 1.6em; border-bottom: 1px solid #d0d7de; padding-bottom: .3em; }
h2 { font-size: 1.25em; margin-top: 1.8em; }
table { border-collapse: collapse; margin: .8em 0; font-size: .88em; }
th, td { border: 1px solid #d0d7de; padding: .3em .6em; text-align: right; white-space: nowrap; }
th { background: #f6f8fa; }
td:nth-child(-n+2) { text-align: left; }
tr.ceiling td { background: #fff8c5; font-style: italic; }
img { max-width: 100%; border: 1px solid #d0d7de; margin: .5em 0; }
p.caption { color: #57606a; font-size: .9em; }
"""


def _html_table(header: list[str], rows: list[list[str]], table_id: str, ceiling_label: str = "oracle ceiling") -> str:
    out = [f'<table id="{table_id}">', "<thead><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr></thead>",
           "<tbody>"]
    for r in rows:
        cls = ' class="ceiling"' if len(r) > 1 and r[1] == ceiling_label else ""
        cells = "".join(f"<td>{c}</td>" for c in r)  # cells are built from numbers and escaped labels
        out.append(f"<tr{cls}>{cells}</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def _escape_rows(rows: list[list[str]], keep_html_from: int) -> list[list[str]]:
    return [[c if i >= keep_html_from else html.escape(c) for i, c in enumerate(r)] for r in rows]


def html_page(data: ReportData) -> str:
    cols = data.columns
    header = ["within", "method"] + [c.name for c in cols]
    body = [f"<h1>{html.escape(data.title)}</h1>",
            '<p class="caption">Success rate (%) on the seeded evaluation states (seed 2024): mean ± standard deviation '
            "over seeds, [95% Wilson interval of the pooled successes]; the best per column in bold (none where all tie). "
            "Ceiling: "
            + html.escape(_bounds(cols)) + ".</p>",
            "<h2>Table 1 — rewards</h2>",
            _html_table(header, _escape_rows(table_rows(data.table1, cols, md=False), 2), "table1", ceiling_label(cols))]
    caption = lookahead_caption(data)
    if caption:
        body += [f'<p class="caption">{html.escape(caption.replace("`", ""))}</p>']
    if data.table2:
        note = table2_caption(data)
        body += ["<h2>Table 2 — algorithms</h2>"]
        body += [f'<p class="caption">{html.escape(note.replace("`", ""))}</p>'] if note else []
        body += [_html_table(header, _escape_rows(table_rows(data.table2, cols, md=False, extra=data.table2_tolerances), 2),
                             "table2", ceiling_label(cols))]
    body += ["<h2>ASAP gap</h2>",
             f'<p class="caption">{html.escape(gap_caption(cols))}</p>',
             _html_table(["method"] + [c.name for c in cols],
                         _escape_rows(gap_rows(unique(data.table1 + data.table2), cols), 99), "gap")]
    for name, title in plot_titles(cols).items():
        if name in data.plots:
            b64 = base64.b64encode(data.plots[name]).decode("ascii")
            body += [f"<h2>{html.escape(title)}</h2>",
                     f'<img id="plot-{name}" alt="{html.escape(title)}" src="data:image/png;base64,{b64}">']
    body += ["<h2>What was run</h2>",
             _html_table(RUN_COLUMNS, _escape_rows(run_rows(data), 99), "runs"),
             "<p>Package versions: " + html.escape(", ".join(f"{k} {v}" for k, v in data.versions.items()))
             + f". Report built in {data.seconds:.1f} s.</p>"]
    for n in data.notes:
        body.append(f"<p><b>Note:</b> {html.escape(n)}</p>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(data.title)}</title><style>{CSS}</style></head>\n<body>\n"
            + "\n".join(body) + "\n</body></html>\n")


def summary(data: ReportData) -> dict:
    """The report's numbers as plain data (``report.json``): per column its ceiling, per method of
    each table its cells (mean, standard deviation and seeds of the rate, pooled interval) at every
    tolerance the table shows, and its ASAP gap; what was run. What others build on the report
    from (docs/results/README.md: :mod:`.paper`)."""
    def rows(methods: list[Method], extra: Sequence[int]) -> list[dict]:
        out = []
        for m in methods:
            cells = {col.name: {str(T): m.cell(col.name, T) for T in _tolerances([col], extra)
                                if T in col.tolerances or T <= col.deadline}
                     for col in data.columns}
            out.append({"key": m.key, "label": m.label, "kind": m.kind, "cells": cells,
                        "gap": {col.name: m.gap(col.name) for col in data.columns}})
        return out

    columns = [{"name": c.name, "spec": _portable(c.spec), "task": c.task, "tolerances": list(c.tolerances),
                "deadline": c.deadline, "bound": c.bound, "black_box": c.black_box,
                "ceiling": {str(T): r for T, r in (c.ceiling or {}).items()}} for c in data.columns]
    return {"title": data.title, "columns": columns, "table1": rows(data.table1, ()),
            "table2": rows(data.table2, data.table2_tolerances), "table2_tolerances": list(data.table2_tolerances),
            "runs": data.runs, "versions": data.versions, "seconds": data.seconds, "notes": list(data.notes)}


def _portable(spec: str) -> str:
    """The spec's path relative to the working directory when it lies under it (``specs/x.asap``
    from a checkout, wherever the checkout is), as given otherwise: a committed report names no
    machine's directories."""
    try:
        return Path(spec).resolve().relative_to(Path.cwd().resolve()).as_posix()
    except (ValueError, OSError):
        return str(spec)


def write(out_dir: Path, data: ReportData) -> dict[str, Path]:
    """Write ``report.md``, ``report.html``, ``report.json`` (:func:`summary`) and ``plots/*.png``
    into ``out_dir`` (atomically)."""
    out_dir = Path(out_dir)
    for name, png in data.plots.items():
        atomic_write(out_dir / "plots" / f"{name}.png", png)
    atomic_write(out_dir / "report.md", markdown(data))
    atomic_write(out_dir / "report.html", html_page(data))
    atomic_write_json(out_dir / "report.json", json_safe(summary(data)))
    return {"markdown": out_dir / "report.md", "html": out_dir / "report.html", "json": out_dir / "report.json"}
