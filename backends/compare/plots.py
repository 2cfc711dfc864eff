"""The report's figures (matplotlib, rendered to PNG bytes). Each takes plain data and returns the
PNG; one subplot per (spec, task) column."""

from __future__ import annotations

import io
import math
from typing import Optional

import numpy as np

from .report import reference, references

__all__ = ["pyplot", "steps_vs_oracle", "success_vs_tolerance", "training_curves", "trajectories"]


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


#: Figures are drawn at this resolution and at least this wide (pixels): a report's page is about
#: 1200 px wide, and a picture narrower than 900 px leaves its labels too small to read.
DPI = 100
MIN_WIDTH = 9.6   # inches: 960 px
MAX_WIDTH = 12.8  # inches: 1280 px, the page's width (wider ones are shrunk, and their fonts with them)
FONT = {"font.size": 11, "axes.titlesize": 11, "axes.labelsize": 11, "legend.fontsize": 10,
        "xtick.labelsize": 10, "ytick.labelsize": 10}


def _figure(n: int, height: float = 3.6, rows_of: int = 1):
    """A grid of ``n`` panels (at most 4 a row; ``rows_of`` rows each), between MIN_WIDTH and
    MAX_WIDTH wide."""
    plt = pyplot()
    plt.rcParams.update(FONT)
    ncols = min(n, 4)
    nrows = math.ceil(n / ncols) * rows_of
    width = min(MAX_WIDTH, max(MIN_WIDTH, 4.8 * ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(width, height * nrows), squeeze=False)
    return plt, fig, axes


def _hide_unused(axes, used: int) -> None:
    for ax in list(axes.flat)[used:]:
        ax.axis("off")


def _legend_below(fig, handles, labels, ncol: Optional[int] = None) -> float:
    """One legend for the figure, centred under its panels (never over the data); returns the
    share of the figure's height it takes, for the layout's rectangle."""
    if not handles:
        return 0.0
    ncol = ncol or min(len(handles), 4)
    rows = math.ceil(len(handles) / ncol)
    share = min(0.45, (0.3 * rows + 0.25) / fig.get_figheight())
    fig.legend(handles, labels, loc="lower center", ncol=ncol, frameon=False, bbox_to_anchor=(0.5, 0.0))
    return share


def _handles(axes) -> tuple[list, list]:
    """Every labelled artist of the panels, each label once."""
    seen, handles, labels = set(), [], []
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in seen:
                seen.add(lab)
                handles.append(h)
                labels.append(lab)
    return handles, labels


def _png(plt, fig, bottom: float = 0.0) -> bytes:
    buf = io.BytesIO()
    fig.tight_layout(rect=(0, bottom, 1, 1))
    fig.savefig(buf, format="png", dpi=DPI)
    plt.close(fig)
    return buf.getvalue()


def _steps(ev: dict) -> np.ndarray:
    return np.array([np.inf if x is None else float(x) for x in ev["per_state"]["t_reach"]])


def success_vs_tolerance(columns, methods) -> bytes:
    """For each column: each method's success rate (pooled over seeds) at every tolerance from 0 to
    the deadline, with the oracle's curve dashed."""
    plt, fig, axes = _figure(len(columns))
    for ax, col in zip(axes.flat, columns):
        T = np.arange(0, col.deadline + 1)
        for m in methods:
            evs = m.evaluations.get(col.name) or []
            if not evs:
                continue
            steps = np.concatenate([_steps(ev) for ev in evs])
            ax.plot(T, [100 * np.mean(steps <= t) for t in T], label=m.label,
                    lw=1.2 if m.kind == "greedy" else 1.6, ls=":" if m.kind == "greedy" else "-")
        if col.oracle_steps is not None:
            o = np.array([np.inf if x is None else x for x in col.oracle_steps], float)
            ax.plot(T, [100 * np.mean(o <= t) for t in T], "k--", lw=1.6, label=f"ceiling ({col.bound})")
        for tol in col.tolerances:
            ax.axvline(tol, color="0.85", lw=0.8, zorder=0)
        ax.set_title(col.name)
        ax.set_xlabel("tolerance (steps)")
        ax.set_ylabel("success (%)")
        ax.set_ylim(0, 101)
        ax.grid(alpha=0.3)
    _hide_unused(axes, len(columns))
    return _png(plt, fig, _legend_below(fig, *_handles(axes)))


def steps_vs_oracle(columns, method) -> Optional[bytes]:
    """Each state's steps to reach under ``method`` (its first seed) against the oracle's minimum
    (the planner's achievable steps for a black box)."""
    cols = [c for c in columns if c.oracle_steps is not None and method.evaluations.get(c.name)]
    if not cols:
        return None
    plt, fig, axes = _figure(len(cols), height=3.6)
    rng = np.random.default_rng(0)
    for ax, col in zip(axes.flat, cols):
        ev = method.evaluations[col.name][0]
        s = _steps(ev)
        o = np.array([np.inf if x is None else x for x in col.oracle_steps], float)
        both = np.isfinite(s) & np.isfinite(o)
        jit = rng.uniform(-0.25, 0.25, size=(2, both.sum()))
        ax.scatter(o[both] + jit[0], s[both] + jit[1], s=9, alpha=0.4)
        miss = np.isfinite(o) & ~np.isfinite(s)
        if miss.any():
            ax.scatter(o[miss], np.full(miss.sum(), col.deadline + 1.5), s=12, marker="x", color="C3",
                       label=f"not reached ({miss.sum()})")
        beat = ~np.isfinite(o) & np.isfinite(s)  # the planner's are achievable steps: a policy may reach where it did not
        if beat.any():
            ax.scatter(np.full(beat.sum(), col.deadline + 1.5), s[beat], s=14, marker="^", color="C2",
                       label=f"reached where the {reference(col.bound)} did not ({beat.sum()})")
        if miss.any() or beat.any():
            ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.22), frameon=False)  # under the panel
        ax.plot([0, col.deadline], [0, col.deadline], "k--", lw=1)
        ax.set_title(f"{col.name}: {method.label}", fontsize=10)
        ax.set_xlabel("planner's achievable steps" if reference(col.bound) == "planner" else "oracle's minimum (steps)")
        ax.set_ylabel("steps to reach")
        ax.grid(alpha=0.3)
    _hide_unused(axes, len(cols))
    return _png(plt, fig)


def _start_label(i: int, ex: dict) -> str:
    """``start 1 (theta 0.52, omega -1.3)``: an example's initial state on its plotted coordinates."""
    phase = ex.get("phase")
    if phase is None or i >= len(phase.policy) or phase.policy[i] is None:
        return f"start {i + 1}"
    x0, names = phase.policy[i][0], phase.scene.names
    shown = [k for pair in phase.scene.projection.pairs for k in pair if k is not None]
    keys = list(dict.fromkeys(shown))[:3] or list(range(min(3, len(x0))))
    return f"start {i + 1} (" + ", ".join(f"{names[k]} {x0[k]:.3g}" for k in keys) + ")"


def trajectories(columns, examples: dict) -> Optional[bytes]:
    """``examples[column name] = {"policy": [rho over time], "oracle": [...], "label": str,
    "phase": Example}``: the robustness of ``asap`` along a few example episodes, one colour per
    start (named in the legend under each panel by its initial state), the policy solid and the
    oracle dashed."""
    from matplotlib.lines import Line2D

    cols = [c for c in columns if c.name in examples]
    if not cols:
        return None
    plt, fig, axes = _figure(len(cols), height=4.6)
    for ax, col in zip(axes.flat, cols):
        ex = examples[col.name]
        for who, ls, lw in (("policy", "-", 1.8), ("oracle", "--", 1.4)):
            reached = ex.get(f"{who}_reached") or []
            for i, rho in enumerate(ex.get(who) or []):
                if rho is None:
                    continue
                label = _start_label(i, ex) if who == "policy" else None
                ax.plot(np.arange(len(rho)), rho, color=f"C{i % 10}", lw=lw, ls=ls, label=label)
                if i < len(reached) and reached[i]:  # each curve ends at its reach point
                    ax.plot(len(rho) - 1, rho[-1], marker="*", ms=11, mfc="white", mec="k", ls="none")
        ax.axhline(0, color="k", lw=0.8)
        ax.set_title(f"{col.name}: {ex['label']}", fontsize=10)
        ax.set_xlabel("step")
        ax.set_ylabel("robustness of asap")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.16), frameon=False, fontsize=9)  # under the panel
    _hide_unused(axes, len(cols))
    style = [Line2D([], [], color="k", lw=1.8, label="policy (solid)"),
             Line2D([], [], color="k", lw=1.4, ls="--", label=f"{references(cols)} (dashed)"),
             Line2D([], [], marker="*", ms=11, mfc="white", mec="k", ls="none", label="reach point (the curve ends)")]
    fig.legend(handles=style, loc="upper center", ncol=3, frameon=False, bbox_to_anchor=(0.5, 1.0))
    buf = io.BytesIO()
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / fig.get_figheight()))
    fig.savefig(buf, format="png", dpi=DPI)
    plt.close(fig)
    return buf.getvalue()


_DASHES = ["-", "--", ":", "-."]


def training_curves(columns, curves: dict) -> Optional[bytes]:
    """``curves[column name] = [(method label, rows)]``, one entry per run (a method's seeds share
    its label), with rows from ``curves.csv``: the validation success at every tolerance (one
    colour per method, its seeds alike; one line style per tolerance) against wall time (top) and
    steps (middle), and the validation return against steps (bottom) where the runs recorded it (a
    ``return`` column). The legend names each method and each tolerance once."""
    from matplotlib.lines import Line2D

    cols = [c for c in columns if curves.get(c.name)]
    if not cols:
        return None
    methods = list(dict.fromkeys(label for c in cols for label, _ in curves[c.name]))
    palette = [f"C{i}" for i in range(10)] if len(methods) <= 10 else [pyplot().cm.tab20(i % 20) for i in range(len(methods))]
    colour = {m: palette[i % len(palette)] for i, m in enumerate(methods)}
    tols = sorted({T for c in cols for T in c.tolerances}, reverse=True)
    dash = {T: _DASHES[d % len(_DASHES)] for d, T in enumerate(tols)}
    has_return = any("return" in r for c in cols for _, rows in curves[c.name] for r in rows)
    per = 3 if has_return else 2
    plt, fig, axes = _figure(len(cols), height=3.0, rows_of=per)
    ncols = min(len(cols), 4)
    for j, col in enumerate(cols):
        panels = [axes[per * (j // ncols) + r, j % ncols] for r in range(per)]
        top, middle = panels[0], panels[1]
        for label, rows in curves[col.name]:
            for T in sorted(col.tolerances, reverse=True):
                key = f"success_{T}"
                have = [r for r in rows if key in r]
                if not have:
                    continue
                y = [100 * float(r[key]) for r in have]
                style = dict(color=colour[label], ls=dash[T], lw=1.4, alpha=0.85)
                top.plot([float(r["seconds"]) for r in have], y, **style)
                middle.plot([int(r["steps"]) for r in have], y, **style)
            if has_return:
                have = [r for r in rows if "return" in r]
                panels[2].plot([int(r["steps"]) for r in have], [float(r["return"]) for r in have],
                               color=colour[label], lw=1.4, alpha=0.85)
        top.set_title(f"{col.name}: validation success", fontsize=10)
        top.set_xlabel("wall time (s)")
        middle.set_xlabel("environment steps")
        for ax in (top, middle):
            ax.set_ylabel("success (%)")
            ax.set_ylim(0, 101)
            ax.grid(alpha=0.3)
        if has_return:
            panels[2].set_xlabel("environment steps")
            panels[2].set_ylabel("validation return\n(each reward its own scale)")
            panels[2].grid(alpha=0.3)
    for ax in axes.flat:
        if not ax.has_data():
            ax.axis("off")
    handles = [Line2D([], [], color=colour[m], lw=2, label=m) for m in methods]
    handles += [Line2D([], [], color="k", ls=dash[T], lw=1.4, label=f"within {T}") for T in tols]
    return _png(plt, fig, _legend_below(fig, handles, [h.get_label() for h in handles], ncol=min(len(handles), 4)))
