"""The CasADi minimum-time oracle: the normal form of ``asap`` (goals), lower bounds on the horizon
(bounds), the NLPs and their initial guesses (nlp), the search over horizons per state (search),
the drivers over many states (solver), the results (results) and their cache.

    from asap_dsl.backends.oracle import run
    report = run(prog, "reach", episodes=100)
"""

from .bounds import HorizonBounds
from .cache import CachedOracle, cache_dir, cache_path, load, oracle_for, solve_seeded, store
from .clock import Work, WorkClock
from .goals import MAX_ALTERNATIVES, Goals, OracleUnsupported
from .nlp import ShootingProblems
from .results import OracleReport, StateResult
from .search import STATE_TIME_LIMIT, Oracle, nearest_neighbour_order
from .solver import DEEP_TASK_SECONDS, deadline_infeasible, run, tighten

__all__ = ["CachedOracle", "DEEP_TASK_SECONDS", "Goals", "HorizonBounds", "MAX_ALTERNATIVES", "Oracle",
           "OracleReport", "OracleUnsupported", "STATE_TIME_LIMIT", "ShootingProblems", "StateResult", "Work",
           "WorkClock", "cache_dir", "cache_path", "deadline_infeasible", "load", "nearest_neighbour_order",
           "oracle_for", "run", "solve_seeded", "store", "tighten"]
