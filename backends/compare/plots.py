"""The report's figures (matplotlib, rendered to PNG bytes). Each takes plain data and returns the
PNG; one subplot per (spec, task) column."""

from __future__ import annotations

import io
import math
from typing import Optional

import numpy as np

__all__ = ["pyplot", "steps_vs_oracle", "success_vs_tolerance", "training_curves", "trajectories"]


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _figure(n: int, height: float = 3.2, rows_of: int = 1):
    plt = pyplot()
    ncols = min(n, 4)
    nrows = math.ceil(n / ncols) * rows_of
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.2 * ncols, height * nrows), squeeze=False)
    return plt, fig, axes


def _hide_unused(axes, used: int) -> None:
    for ax in list(axes.flat)[used:]:
        ax.axis("off")


def _png(plt, fig) -> bytes:
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=90)
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
    axes.flat[0].legend(fontsize=7, loc="upper left")
    _hide_unused(axes, len(columns))
    return _png(plt, fig)


def steps_vs_oracle(columns, method) -> Optional[bytes]:
    """Each state's steps to reach under ``method`` (its first seed) against the oracle's minimum."""
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
        ax.scatter(o[both] + jit[0], s[both] + jit[1], s=5, alpha=0.35)
        miss = np.isfinite(o) & ~np.isfinite(s)
        if miss.any():
            ax.scatter(o[miss], np.full(miss.sum(), col.deadline + 1.5), s=6, marker="x", color="C3",
                       label=f"not reached ({miss.sum()})")
            ax.legend(fontsize=7, loc="lower right")
        ax.plot([0, col.deadline], [0, col.deadline], "k--", lw=1)
        ax.set_title(f"{col.name}: {method.label}")
        ax.set_xlabel("oracle's minimum (steps)")
        ax.set_ylabel("steps to reach")
        ax.grid(alpha=0.3)
    _hide_unused(axes, len(cols))
    return _png(plt, fig)


def trajectories(columns, examples: dict) -> Optional[bytes]:
    """``examples[column name] = {"policy": [rho over time], "oracle": [...], "label": str}``: the
    robustness of ``asap`` along a few example episodes, the policy solid and the oracle dashed."""
    cols = [c for c in columns if c.name in examples]
    if not cols:
        return None
    plt, fig, axes = _figure(len(cols))
    for ax, col in zip(axes.flat, cols):
        ex = examples[col.name]
        for i, rho in enumerate(ex["policy"]):
            ax.plot(np.arange(len(rho)), rho, color=f"C{i}", lw=1.5, label=f"state {i}" if i < 6 else None)
        for i, rho in enumerate(ex.get("oracle") or []):
            if rho is not None:
                ax.plot(np.arange(len(rho)), rho, color=f"C{i}", lw=1.2, ls="--")
        ax.axhline(0, color="k", lw=0.8)
        ax.set_title(f"{col.name}: {ex['label']} (solid), oracle (dashed)", fontsize=9)
        ax.set_xlabel("step")
        ax.set_ylabel("robustness of asap")
        ax.grid(alpha=0.3)
    _hide_unused(axes, len(cols))
    return _png(plt, fig)


def training_curves(columns, curves: dict) -> Optional[bytes]:
    """``curves[column name] = [(label, rows)]`` with rows from ``curves.csv``: the validation
    success at the tightest tolerance against wall time (top) and steps (bottom)."""
    cols = [c for c in columns if curves.get(c.name)]
    if not cols:
        return None
    plt, fig, axes = _figure(len(cols), height=2.8, rows_of=2)
    ncols = min(len(cols), 4)
    for j, col in enumerate(cols):
        top = axes[2 * (j // ncols), j % ncols]
        bottom = axes[2 * (j // ncols) + 1, j % ncols]
        T = min(col.tolerances)
        for label, rows in curves[col.name]:
            key = f"success_{T}"
            rows = [r for r in rows if key in r]
            if not rows:
                continue
            y = [100 * float(r[key]) for r in rows]
            top.plot([float(r["seconds"]) for r in rows], y, lw=1.2, label=label)
            bottom.plot([int(r["steps"]) for r in rows], y, lw=1.2, label=label)
        top.set_title(f"{col.name}: validation success within {T}", fontsize=9)
        top.set_xlabel("wall time (s)")
        bottom.set_xlabel("environment steps")
        for ax in (top, bottom):
            ax.set_ylabel("success (%)")
            ax.set_ylim(0, 101)
            ax.grid(alpha=0.3)
        if j == 0:
            top.legend(fontsize=6, loc="lower right")
    for ax in axes.flat:
        if not ax.has_data():
            ax.axis("off")
    return _png(plt, fig)
