"""The CasADi minimum-time oracle: the normal form of ``asap`` (goals), lower bounds on the horizon
(bounds), the NLP and its search over horizons (solver), its results (results) and their cache.

    from asap_dsl.backends.oracle import run
    report = run(prog, "reach", episodes=100)
"""

from .cache import CachedOracle, cache_dir, cache_path, load, oracle_for, store
from .goals import MAX_ALTERNATIVES, OracleUnsupported
from .results import OracleReport, StateResult
from .solver import (DEEP_TASK_SECONDS, STATE_TIME_LIMIT, Oracle, deadline_infeasible, nearest_neighbour_order, run,
                     tighten)

__all__ = ["CachedOracle", "DEEP_TASK_SECONDS", "MAX_ALTERNATIVES", "Oracle", "OracleReport", "OracleUnsupported",
           "STATE_TIME_LIMIT", "StateResult", "cache_dir", "cache_path", "deadline_infeasible", "load",
           "nearest_neighbour_order", "oracle_for", "run", "store", "tighten"]
