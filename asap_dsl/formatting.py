"""How numbers read in every message and report: one function per kind of number.

The widths differ per use (a column of a table, a word in a sentence), so they are parameters;
what a number looks like (six significant digits, one decimal of a percent) is decided here.
"""

from __future__ import annotations

import math
from typing import Optional

__all__ = ["number", "percent", "plural", "steps_text"]


def number(x: float) -> str:
    """A constant, bound or count as a spec would write it: six significant digits, ``inf``/``-inf``
    for unbounded values (``30``, ``0.1``, ``1e+06``)."""
    return f"{x:.6g}"


def percent(x: Optional[float], width: int = 0, sign: str = "%", missing: str = "n/a") -> str:
    """A rate in [0, 1] as a percent with one decimal, right-aligned in ``width`` characters
    (before ``sign``); ``missing`` stands for None or a non-finite rate (nothing was measured)."""
    if x is None or not math.isfinite(x):
        return missing
    return format(100 * x, f"{width}.1f" if width else ".1f") + sign


def plural(n: int, word: str) -> str:
    """``1 error``, ``2 errors``: a count with its noun (a regular plural)."""
    return f"{n} {word}{'s' if n != 1 else ''}"


def steps_text(summary: dict) -> str:
    """``min 4, 25% 6, median 7, 75% 9, max 14, mean 7.31``: a
    :func:`asap_dsl.stats.steps_summary` of states that reached (``summary["reached"] > 0``)."""
    s = summary
    return (f"min {s['min']:.0f}, 25% {s['p25']:.0f}, median {s['median']:.0f}, 75% {s['p75']:.0f}, "
            f"max {s['max']:.0f}, mean {s['mean']:.2f}")
