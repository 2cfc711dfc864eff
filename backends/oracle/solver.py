"""The minimum-time oracle: the fewest steps in which *any* admissible policy can fulfil a task.

For a task whose ``asap`` is built from conditions on the state (regions ``in R`` and comparisons
such as ``x > 4``) with ``not``, ``and``, ``or``, ``->`` and the past operators ``historically``
and ``once`` over windows (unfolded into one condition per step of the window: a dwell
``historically[0, 2] in home`` constrains the last three states), and whose ``avoid`` is such a
condition without temporal operators, on a system with known dynamics (``ode`` or ``map``), the
oracle computes for each initial state x0 the smallest N such that some action sequence within
the action bounds reaches ``asap`` at step N, with ``avoid`` false and the state inside the state
space at steps 1..N, under the simulator's very discretisation (:func:`asap_dsl.dynamics.casadi_step`).

Where
-----
* the normal form of ``asap`` and ``avoid``: :mod:`asap_dsl.backends.oracle.goals`;
* lower bounds on N (linearity, support functions, interval reachability):
  :mod:`asap_dsl.backends.oracle.bounds`;
* the elastic multiple-shooting NLPs and their initial guesses: :mod:`asap_dsl.backends.oracle.nlp`;
* the search over N per state, multi-start, replay, verification and labels (``exact`` or
  ``local``): :class:`asap_dsl.backends.oracle.search.Oracle`;
* here: :func:`run` over many states (in worker processes), :func:`tighten` (consistency between
  tasks sharing ``asap``) and :func:`deadline_infeasible` (``lint --deep``);
* the results: :mod:`asap_dsl.backends.oracle.results`; their cache: :mod:`asap_dsl.backends.oracle.cache`.

Per-state statuses: ``solved`` (a minimum N found), ``infeasible`` (no N up to the deadline;
clean solves), ``solver_failed`` (no N found and IPOPT failed at some N), ``timeout`` (the
search used up its time, :data:`STATE_TIME_LIMIT` by default, before deciding: no N up to
``horizon``), ``nan`` (a non-finite initial state or dynamics). Solver failures never raise.
"""

from __future__ import annotations

import itertools
import os
import sys
import time
from dataclasses import replace
from typing import Callable, Optional, Sequence

import numpy as np

from asap_dsl.processes import pool_size, pool_worker, wall_timeout
from asap_dsl.sampling import EVAL_SEED, task_states
from asap_dsl.stl import ir

from .clock import WorkClock
from .goals import OracleUnsupported
from .results import OracleReport, StateResult
from .search import STATE_TIME_LIMIT, Oracle, nearest_neighbour_order

__all__ = ["DEEP_TASK_SECONDS", "STATE_TIME_LIMIT", "OracleUnsupported", "deadline_infeasible", "run", "tighten"]


# --------------------------------------------------------------------------- consistency
def tighten(prog, reports: Sequence["OracleReport"]) -> dict[str, int]:
    """Make the local minima of tasks sharing an ``asap`` consistent; returns, per task, how
    many states improved.

    Where one task's constraints (``avoid``, deadline) are a superset of another's — ``reach_avoid``
    against ``reach`` — each of its action sequences is also admissible for the other, so a
    state's ``reach`` minimum cannot exceed its ``reach_avoid`` minimum; a local search can still
    miss it. For every pair of reports of ``prog`` with the same ``asap`` (states matched by
    their x0), each action sequence found for one task is replayed under the other task's own
    check (:meth:`Oracle.first_passing_prefix`, the simulator's step) and adopted when its
    shortest passing prefix is shorter than that state's minimum (or the state had none, or an
    unverified one). Sequences of the less constrained task are tried too: they count when their
    replay happens to satisfy the stricter task. Every adopted sequence is verified by replay; the
    result records the task it came from in ``source``. Reports are changed in place and each
    gets ``extra["tightened"]``.
    """
    oracles = {rep.task: Oracle(prog, rep.task, restarts=0) for rep in reports}  # no NLP is built
    originals = {id(rep): list(rep.results) for rep in reports}
    summary: dict[str, int] = {}
    for rep in reports:
        o = oracles[rep.task]
        asap = ir.to_text(o.task.model.asap)
        by_x0 = {np.asarray(r.x0, float).tobytes(): i for i, r in enumerate(rep.results)}
        improved: set[int] = set()
        sources: list[str] = []
        for other in reports:
            if other is rep or other.task == rep.task or other.system != rep.system:
                continue
            if ir.to_text(oracles[other.task].task.model.asap) != asap:
                continue
            sources.append(other.task)
            for r in originals[id(other)]:
                if r.steps is None or r.actions is None or r.steps == 0:
                    continue
                i = by_x0.get(np.asarray(r.x0, float).tobytes())
                if i is None:
                    continue
                cur = rep.results[i]
                if cur.steps is not None and cur.verified and cur.steps <= r.steps:
                    continue
                acts = np.asarray(r.actions, float)[: o.deadline]
                k = o.first_passing_prefix(cur.x0, acts)
                if k is None or (cur.steps is not None and cur.verified and k >= cur.steps):
                    continue
                tr, ok = o.replay(cur.x0, acts[:k])
                if not ok:  # first_passing_prefix checked the same replay: never here
                    continue
                rep.results[i] = replace(cur, steps=k, status="solved", verified=True, actions=acts[:k],
                                         trajectory=tr, source=other.task)
                improved.add(i)
        rep.extra["tightened"] = {"from": sources, "improved_states": len(improved)}
        summary[rep.task] = len(improved)
    return summary


# --------------------------------------------------------------------------- drivers
#: States per chunk of a search under a budget (a worker stops within its chunk once the budget is
#: spent). A chunk warm-starts along its part of the tour; at 8 states, a fifth of attitude's timed
#: out at 5 s.
BUDGET_CHUNK = 32

_WORKER_ORACLES: dict = {}  # in a worker process: one Oracle (and its built solvers) per setting


def _worker(payload):
    """Process entry: re-load the spec from its text (programs hold compiled closures), once per
    process and setting: the chunks a worker solves share its solvers (and, on the wall clock,
    its warm starts)."""
    import asap_dsl

    source, name, task, states, indices, ipopt, restarts, interval_bound, time_limit, clock, until, budget = payload
    key = (source, name, task, repr(ipopt), restarts, interval_bound, time_limit, clock)
    oracle = _WORKER_ORACLES.get(key)
    if oracle is None:
        _WORKER_ORACLES.clear()
        oracle = _WORKER_ORACLES[key] = Oracle(asap_dsl.loads(source, name), task, ipopt, restarts, interval_bound,
                                               time_limit, clock)
    return [r.to_dict(with_actions=True) for r in oracle.solve_many(states, indices, until=until, budget=budget)]


def run(prog, task: Optional[str] = None, episodes: int = 1000, seed: int = EVAL_SEED, workers: int = 1,
        states: Optional[np.ndarray] = None, ipopt_options: Optional[dict] = None,
        restarts: Optional[int] = None, interval_bound: bool = True,
        time_limit: float = STATE_TIME_LIMIT, progress: Optional[Callable[[int], None]] = None,
        budget_seconds: Optional[float] = None, clock: Optional[WorkClock] = None,
        wall_seconds: Optional[float] = None, done: Sequence[StateResult] = (),
        on_part: Optional[Callable[[list[StateResult]], None]] = None) -> OracleReport:
    """The oracle's minimum time from each of ``episodes`` seeded initial states (or the given
    ``states``) of one task.

    :param prog: the program (:func:`asap_dsl.load`); its system must be an ``ode`` or a ``map``.
    :param task: the task's name (default: the program's only or first task, as ``prog.task``).
    :param episodes: how many initial states to draw from the task's initial box (ignored with
        ``states``).
    :param seed: the seed of those states (default 2024, the states every method is evaluated on).
    :param workers: processes to solve in. More than one splits the nearest-neighbour tour into
        contiguous chunks, about eight per worker so that the work stays balanced and progress is
        seen; each process builds its own solvers and warm-starts along its own chunks (``exact``
        minima do not depend on it; ``local`` ones may).
    :param states: the initial states ``[k, n]`` themselves (the report's seed is then None).
    :param ipopt_options: ``nlpsol`` options over :data:`asap_dsl.backends.oracle.nlp.IPOPT_OPTIONS`.
    :param restarts: extra initial guesses per horizon before it is declared infeasible (default
        :data:`~asap_dsl.backends.oracle.search.RESTARTS` on non-linear systems, 0 on linear ones).
    :param interval_bound: start the search of non-linear systems at the interval lower bound.
    :param time_limit: seconds of search per state, then ``timeout``.
    :param progress: called as ``progress(k)`` when k more states are done.
    :param budget_seconds: stop once these seconds are spent: the states are taken along the
        tour in chunks of :data:`BUDGET_CHUNK`, and those not begun by then are left out
        of the report (its ``results`` are then the solved states', in input order). The workers
        and their solvers live for the whole search: a pool per chunk built every horizon's NLP
        again and lost the warm starts (attitude: 1.2 s per state and worker, against 0.35 s).
    :param clock: read ``time_limit`` and ``budget_seconds`` on this simulated clock
        (:mod:`.clock`): the tour is cut into chunks of :data:`BUDGET_CHUNK` whatever the workers,
        each starts cold and gets its states' share of the budget, so that what is found is the
        same on every machine and any number of workers (the budget is then CPU seconds: on one
        core the search takes longer, it does not find less).
    :param wall_seconds: a cap on the wall clock as well: no state is begun after it (a run's time
        limit).
    :param done: results of some of these states already found (an interrupted search's, by
        index): not solved again, and in the report as they are.
    :param on_part: called with each chunk's results as it ends (the caller keeps them, so that an
        interrupted search resumes: :func:`~asap_dsl.backends.oracle.cache.oracle_for`).
    :return: the per-state results (in input order) and the ceiling per tolerance.
    :raises OracleUnsupported: a black-box system, or a task outside what the oracle solves.
    :raises KeyError: an unknown task.
    :raises ValueError: a time limit that is not a positive number.
    """
    start = time.perf_counter()
    oracle = Oracle(prog, task, ipopt_options, restarts, interval_bound, time_limit, clock)  # validates up front
    t = oracle.task.model
    if states is None:
        states = task_states(prog.system, t, episodes, seed=seed)
        used_seed: Optional[int] = seed
    else:
        used_seed = None
    states = np.asarray(states, float).reshape(-1, oracle.n)

    # No state is begun after this wall-clock time (the workers read it too: the overrun is one state's).
    walls = [w for w in (wall_seconds, budget_seconds if clock is None else None) if w is not None]
    cap = min(walls) if walls else 0.0
    until = None if not walls else time.time() + max(0.0, cap - (time.perf_counter() - start))

    def spent() -> bool:
        return until is not None and time.time() >= until

    done = list(done)
    known = {r.index for r in done}
    order = [i for i in nearest_neighbour_order(states, prog.system) if i not in known]
    if clock is not None or until is not None:  # chunks of the tour, taken until the wall's budget is spent
        chunks = [order[lo:lo + BUDGET_CHUNK] for lo in range(0, len(order), BUDGET_CHUNK)]
    else:
        pieces = max(1, min(len(order), 8 * int(workers)))
        chunks = [list(c) for c in np.array_split(np.asarray(order), pieces) if len(c)]
    # On the clock each chunk has its states' share of the budget (whoever solves it, whenever).
    shares = [None if clock is None or budget_seconds is None else budget_seconds * len(c) / len(states)
              for c in chunks]
    workers = pool_size(max(1, min(int(workers), len(chunks))))

    if workers == 1 and until is None and clock is None and not done and on_part is None:
        results = oracle.solve_many(states, progress=progress)
    elif workers == 1:
        by_index = {r.index: r for r in done}
        for chunk, share in zip(chunks, shares):
            if spent():
                break
            part = oracle.solve_many(states[chunk], indices=chunk, progress=progress, until=until, budget=share)
            by_index.update((r.index, r) for r in part)
            if on_part is not None:
                on_part(part)
        results = [by_index[i] for i in sorted(by_index)]
    else:
        import multiprocessing as mp

        payloads = [(prog.source, prog.file, oracle.task_name, states[c], [int(i) for i in c], ipopt_options,
                     restarts, interval_bound, time_limit, clock, until, share) for c, share in zip(chunks, shares)]
        # Forked where it is safe (quicker to start); spawned once a learner's library is loaded (a
        # training run's demonstrations, `asapc eval`): forking JAX's or torch's threads may
        # deadlock, and JAX warns the user so.
        learner = "jax" in sys.modules or "torch" in sys.modules
        method = "fork" if "fork" in mp.get_all_start_methods() and not learner else "spawn"
        parts = []
        with mp.get_context(method).Pool(workers, initializer=pool_worker, initargs=(os.getpid(),)) as pool:
            pending = iter(payloads)
            running = []
            # Two chunks per worker in flight (one queued behind the one it solves), the next as one ends.
            for payload in itertools.islice(pending, 2 * workers):
                running.append(pool.apply_async(_worker, (payload,)))
            while running:
                try:
                    part = running.pop(0).get(wall_timeout(until, cap, time_limit))
                except mp.TimeoutError:  # past the wall's cap: what still runs is given up
                    break
                parts.append(part)
                if on_part is not None:
                    on_part([StateResult.from_dict(d) for d in part])
                if progress is not None:
                    progress(len(part))
                nxt = None if spent() else next(pending, None)
                if nxt is not None:
                    running.append(pool.apply_async(_worker, (nxt,)))
        by_index = {r.index: r for r in done}
        by_index.update((d["index"], StateResult.from_dict(d)) for part in parts for d in part)
        results = [by_index[i] for i in sorted(by_index)]
    for r in results:  # trajectories are neither shipped back nor kept: replay here (cheap)
        if r.actions is not None and r.trajectory is None:
            r.trajectory, _ = oracle.replay(r.x0, r.actions)
    return OracleReport(prog.file, oracle.task_name, prog.system.name, oracle.label, oracle.deadline,
                        oracle.tolerances, used_seed, results, time.perf_counter() - start, workers)


#: ``lint --deep`` searches at most about this many seconds per task (split over its samples).
DEEP_TASK_SECONDS = 60.0


def deadline_infeasible(prog, task_name: Optional[str] = None, samples: int = 32, seed: int = 0,
                        workers: int = 2, seconds: float = DEEP_TASK_SECONDS) -> list[tuple[np.ndarray, str, str]]:
    """Sampled initial states that were not shown to reach ``asap`` within the deadline (for
    ``lint --deep``): ``(state, status, reason)``, the status ``infeasible``, ``solver_failed``,
    ``nan`` or ``timeout`` (the search of that state used up its share of ``seconds``, the
    time for the task), the reason a few words. Empty when every sample reaches the goal
    in time. Raises :class:`OracleUnsupported` for a black-box system or a non-region task."""
    workers = max(1, min(workers, samples))
    per_state = max(0.5, seconds * workers / max(1, samples))
    oracle = Oracle(prog, task_name, time_limit=per_state)
    states = task_states(prog.system, oracle.task.model, samples, seed=seed)
    report = run(prog, oracle.task_name, states=states, workers=workers, time_limit=per_state)
    how = {
        "infeasible": "proved by a convex problem" if oracle.label == "exact" else "a local search (IPOPT) found no way",
        "solver_failed": "the solver failed",
        "nan": "the dynamics give non-finite values",
    }
    out = []
    for r in report.results:
        if r.status == "timeout":
            out.append((r.x0, r.status, f"no way found in {per_state:.3g} s of search, which reached "
                        f"{r.horizon:,} of the {oracle.deadline:,} steps"))
        elif r.status in how:
            out.append((r.x0, r.status, how[r.status]))
    return out
