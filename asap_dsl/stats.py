"""Statistics every report shares: success rates with Wilson intervals, steps-to-reach summaries
and the ASAP gap. Pure functions of arrays; nothing here knows about runs or files.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

__all__ = ["Z95", "asap_gap", "rate", "steps_summary", "wilson_interval"]

Z95 = 1.959963984540054  # the standard normal's 97.5% quantile


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The 95% Wilson score interval of a proportion ``k / n`` (``(0, 1)`` when ``n = 0``)."""
    if n <= 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    lo = 0.0 if k == 0 else max(0.0, centre - half)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return (lo, hi)


def rate(successes: np.ndarray) -> dict:
    """``{"count", "states", "rate", "ci95"}`` of a boolean array; the rate is None when empty."""
    s = np.asarray(successes, dtype=bool)
    n, k = int(s.size), int(s.sum())
    return {"count": k, "states": n, "rate": (k / n) if n else None, "ci95": list(wilson_interval(k, n))}


def steps_summary(steps: np.ndarray) -> dict:
    """Quartiles and mean of the finite entries of ``steps`` (the states that reached)."""
    s = np.asarray(steps, dtype=np.float64)
    s = s[np.isfinite(s)]
    if s.size == 0:
        return {"reached": 0}
    q = np.percentile(s, [0, 25, 50, 75, 100])
    return {"reached": int(s.size), "min": float(q[0]), "p25": float(q[1]), "median": float(q[2]),
            "p75": float(q[3]), "max": float(q[4]), "mean": float(np.mean(s))}


def asap_gap(steps: np.ndarray, minimum: np.ndarray) -> dict:
    """The ASAP gap: the median, over the states both reach, of ``steps / minimum``.

    ``steps`` are a method's steps to reach per state, ``minimum`` the oracle's (``inf`` where
    not reached). A state the oracle reaches at step 0 (``asap`` already holds) has nothing to
    gain and is left out, as are states either side does not reach. Returns ``{"gap", "states",
    "p75", "share_optimal"}``; ``gap`` is None (with ``reason``) when no state qualifies.
    ``share_optimal`` is the share of those states reached in the oracle's minimum (or fewer: the
    oracle's local minima are upper bounds).
    """
    a = np.asarray(steps, dtype=np.float64)
    b = np.asarray(minimum, dtype=np.float64)
    both = np.isfinite(a) & np.isfinite(b) & (b > 0)
    if not both.any():
        return {"gap": None, "states": 0, "p75": None, "share_optimal": None,
                "reason": "no state is reached by both the method and the oracle"}
    ratio = a[both] / b[both]
    return {"gap": float(np.median(ratio)), "states": int(both.sum()), "p75": float(np.percentile(ratio, 75)),
            "share_optimal": float(np.mean(a[both] <= b[both]))}


def mean_spread(values: list[Optional[float]]) -> dict:
    """Mean and standard deviation over seeds of the finite values (None entries are skipped)."""
    v = np.array([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else 0.0, "n": int(v.size)}
