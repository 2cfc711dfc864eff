"""The planner over many initial states: a pilot, the states in worker processes, an exchange of
sequences between states, the replay that decides what counts, and consistency between tasks.

:func:`plan_states` is to the planner what :func:`asap_dsl.backends.oracle.solver.run` is to the
oracle: the same seeded states (seed 2024, the states ``asapc eval`` uses), workers, progress and
per-state time limit, and an :class:`~asap_dsl.backends.oracle.results.OracleReport` whose label
is ``achievable`` and whose bound is ``planner (achievable)``: every state's steps are those of a
sequence that the project's own rollout replays to the goal, an upper bound on that state's
minimum, so each rate is a lower bound on the ceiling.

The steps, all deterministic (a state's random numbers are seeded by the seed and the state):

1. **pilot**: the centre of the task's initial box is planned with coarser knots (``pilot_hold``)
   and ``pilot`` times the iterations. Where sampling finds nothing (on dynamics where moving
   first takes the system away from the goal, as the swimmer's every stroke does),
   finite-difference descents start from the most promising periodic sequences
   (:meth:`~asap_dsl.backends.oracle.planner.Planner.periodic`) until one reaches. What it found
   is then shortened (:meth:`~asap_dsl.backends.oracle.planner.Planner.shorten`: compressed in
   time, descended at the shorter horizon) within ``pilot`` times the per-state time limit.
   Every sequence on the way is a warm start of every state (a longer one may reach from a
   state where the shortest does not).
2. **states**: each state is planned with the budget, warm-started from the pilot.
3. **exchange**: the shortest sequences found (``exchange``, from different states) are tried
   from every state, and the shortest passing one is kept (states close together share a plan).
4. **replay**: every state's sequence is rolled out once more, all states in one batch of the
   task's environment (:class:`asap_dsl.rollout.Evaluator`, as every controller is judged); its
   first step in ``asap`` is the state's steps. A sequence that does not reach there is not
   counted (status ``unverified``).
"""

from __future__ import annotations

import os
import time
from dataclasses import replace
from typing import Callable, Optional, Sequence

import numpy as np

from asap_dsl.processes import pool_size, wall_timeout
from asap_dsl.rollout import Evaluator
from asap_dsl.sampling import EVAL_SEED, task_states
from asap_dsl.stl import ir

from .planner import BOUND, LABEL, PlannedState, Planner, PlannerBudget, SequenceController
from .results import OracleReport
from .search import STATE_TIME_LIMIT

__all__ = ["plan_states", "replay_counted", "shortest_sequences", "tighten_planned"]


def _pad(actions: Sequence[Optional[np.ndarray]], steps: int, m: int) -> np.ndarray:
    """Sequences of any lengths (None: none) as one array ``[N, steps, m]``, zeros after their end."""
    out = np.zeros((len(actions), steps, m))
    for i, a in enumerate(actions):
        if a is not None and len(a):
            a = np.asarray(a, dtype=np.float64).reshape(-1, m)[:steps]
            out[i, : len(a)] = a
    return out


def replay_counted(prog, task: str, results: Sequence[PlannedState]) -> list[PlannedState]:
    """Replay every state's sequence in the task's environment (one batch) and keep only what
    the replay confirms: a state's steps become the replay's first step in ``asap`` (None, status
    ``unverified``, where it does not reach within the deadline)."""
    results = list(results)
    with_seq = [i for i, r in enumerate(results) if r.steps is not None and r.actions is not None]
    if not with_seq:
        return results
    m = prog.system.n_action
    x0 = np.array([results[i].x0 for i in with_seq], dtype=np.float64)
    ev = Evaluator(prog, task, x0)
    res = ev.run(SequenceController(_pad([results[i].actions for i in with_seq], ev.steps, m)))
    out = list(results)
    for j, i in enumerate(with_seq):
        r, t = results[i], res.t_reach[j]
        if np.isfinite(t):
            k = int(t)
            out[i] = replace(r, steps=k, actions=np.asarray(r.actions, float).reshape(-1, m)[:k], verified=True,
                             status="solved")
        else:
            out[i] = replace(r, steps=None, verified=False, status="unverified")
    return out


# --------------------------------------------------------------------------- workers
_WORKER: dict = {}  # in a worker process: one Planner per setting (its environment built once)


def _planner(source: str, name: str, task: str, budget: PlannerBudget, time_limit: float, seed: int) -> Planner:
    import asap_dsl

    key = (source, name, task, budget, time_limit, seed)
    if key not in _WORKER:
        _WORKER.clear()
        _WORKER[key] = Planner(asap_dsl.loads(source, name), task, budget, time_limit, seed)
    return _WORKER[key]


def _plan_chunk(payload) -> list[dict]:
    """Process entry: plan (``warm`` given) or exchange (``pool`` given) a chunk of states."""
    source, name, task, budget, time_limit, seed, states, indices, warm, pool, own, until = payload
    planner = _planner(source, name, task, budget, time_limit, seed)
    out = []
    for k, (x0, i) in enumerate(zip(states, indices)):
        if until is not None and time.time() >= until:  # the wall-clock cap: no state begun after it
            break
        if pool is None:
            r = planner.plan(x0, i, warm=warm)
        else:
            r = planner.exchange(x0, i, pool, None if own[k] is None else PlannedState.from_dict(own[k]))
        out.append(r.to_dict(with_actions=True))
    return out


def _threads_for_workers(parent: int) -> None:
    """One MuJoCo thread per worker process (the workers are the parallelism), unless set; and
    the pool worker's signals and death with its owner, as the oracle's pool sets them."""
    from asap_dsl.processes import pool_worker
    from asap_dsl.sim.mujoco_swimmer import THREADS_ENV

    os.environ.setdefault(THREADS_ENV, "1")
    pool_worker(parent)


def _map(payloads: list, workers: int, progress: Optional[Callable[[int], None]],
         wait: Callable[[], Optional[float]] = lambda: None) -> list[PlannedState]:
    """Run the chunks (in ``workers`` processes when more than one); results by index. ``wait()``:
    how long the next result may still be waited for (None: for ever; a wall-clock cap's,
    :func:`~asap_dsl.processes.wall_timeout`), past which the chunks still running are given up."""
    parts: list = []
    if pool_size(workers) == 1:
        for p in payloads:
            parts.append(_plan_chunk(p))
            if progress is not None:
                progress(len(parts[-1]))
    else:
        import multiprocessing as mp

        # Spawned, never forked: the parent has stepped the simulator (the pilot, the first task),
        # and a forked worker that frees an inherited MuJoCo thread pool waits in
        # pthread_cond_destroy for threads that only exist in the parent: for ever (seen on the
        # swimmer's second task; reproduced with a forked pool whose child collects an inherited
        # MujocoSwimmer(nthread=2)). A spawned worker starts clean.
        with mp.get_context("spawn").Pool(workers, initializer=_threads_for_workers, initargs=(os.getpid(),)) as pool:
            results = pool.imap_unordered(_plan_chunk, payloads)
            for _ in payloads:
                try:
                    part = results.next(wait())
                except mp.TimeoutError:
                    break
                parts.append(part)
                if progress is not None:
                    progress(len(part))
    return [PlannedState.from_dict(d) for part in parts for d in part]


def plan_states(prog, task: Optional[str] = None, episodes: int = 1000, seed: int = EVAL_SEED, workers: int = 1,
                states: Optional[np.ndarray] = None, budget: Optional[PlannerBudget] = None,
                time_limit: float = STATE_TIME_LIMIT, progress: Optional[Callable[[int], None]] = None,
                warm: Sequence[np.ndarray] = (), budget_seconds: Optional[float] = None) -> OracleReport:
    """The planner's achievable steps from each of ``episodes`` seeded initial states (or the
    given ``states``) of one task (module docstring).

    :param prog: the program (:func:`asap_dsl.load`); any system, a black box included.
    :param task: the task's name (default: the program's only or first task).
    :param episodes: how many initial states to draw from the task's initial box.
    :param seed: the seed of those states, and of the planner's random numbers.
    :param workers: processes to plan in; the results do not depend on it.
    :param states: the initial states ``[k, n]`` themselves (the report's seed is then None).
    :param budget: samples, iterations and the search's settings (:class:`PlannerBudget`).
    :param time_limit: seconds of search per state (the pilot: ``pilot`` times as many).
    :param progress: called as ``progress(k)`` when k more states are planned.
    :param warm: action sequences every state (and the pilot) tries first: another task's
        (``asapc oracle`` passes each task the shortest sequences of the tasks before it that
        share its ``asap``).
    :param budget_seconds: a cap on the wall clock, whatever the budget's clock (a training run's
        time limit): no state is begun once these seconds are spent, and those not begun are left
        out of the report (its ``results`` are then the planned states', in input order), as
        :func:`~asap_dsl.backends.oracle.solver.run` does; the exchange stops there too.
    :return: a report labelled ``achievable`` (``extra``: ``bound``, ``planner`` with the budget,
        the pilot and the exchange).
    :raises PlannerUnsupported: a simulator that cannot be started from a given state.
    :raises KeyError: an unknown task.
    """
    start = time.perf_counter()
    until = None if budget_seconds is None else time.time() + max(0.0, float(budget_seconds))
    budget = budget or PlannerBudget()
    planner = Planner(prog, task, budget, time_limit, seed)  # validates the task and the simulator
    tm = planner.task.model
    if states is None:
        states = task_states(prog.system, tm, episodes, seed=seed)
        used_seed: Optional[int] = seed
    else:
        used_seed = None
    states = np.asarray(states, float).reshape(-1, planner.n)
    workers = max(1, min(int(workers), len(states)))
    pilot, found = _pilot(prog, planner, budget, time_limit, seed, warm)
    warm = found + [np.asarray(w, float) for w in warm]
    n_chunks = min(len(states), 8 * workers)  # in one process too: progress after each chunk
    chunks = [c for c in np.array_split(np.arange(len(states)), n_chunks) if len(c)]
    common = (prog.source, prog.file, planner.task_name, budget, time_limit, seed)

    def wait() -> Optional[float]:
        return wall_timeout(until, float(budget_seconds or 0.0), time_limit)

    planned = _map([common + (states[c], [int(i) for i in c], warm, None, None, until) for c in chunks],
                   workers, progress, wait)
    by_index = {r.index: r for r in planned}
    results = [by_index[i] for i in range(len(states)) if i in by_index]
    pool = shortest_sequences(results, budget.exchange)
    exchanged = 0
    if pool and (until is None or time.time() < until):
        at = {r.index: k for k, r in enumerate(results)}  # under a cap, only the planned states
        own = {r.index: r.to_dict(with_actions=True) for r in results}
        kept = [c for c in (c[np.isin(c, list(at))] for c in chunks) if len(c)]
        again = _map([common + (states[c], [int(i) for i in c], None, pool, [own[int(i)] for i in c], until)
                      for c in kept], workers, None, wait)
        for r in again:
            cur = results[at[r.index]]
            if r.steps is not None and (cur.steps is None or r.steps < cur.steps):
                results[at[r.index]] = r
                exchanged += 1
    results = replay_counted(prog, planner.task_name, results)
    extra = {"bound": BOUND, "planner": {**budget.to_dict(), "time_limit": time_limit, "seed": seed,
                                         "pilot_run": {"x0": [float(v) for v in pilot.x0], "steps": pilot.steps,
                                                   "rollouts": pilot.rollouts, "seconds": round(pilot.seconds, 3)},
                                         "exchange": {"sequences": len(pool), "improved_states": exchanged},
                                         "rollouts": int(sum(r.rollouts for r in results))}}
    return OracleReport(prog.file, planner.task_name, prog.system.name, LABEL, planner.deadline, planner.tolerances,
                        used_seed, results, time.perf_counter() - start, workers, extra)


def _pilot(prog, planner: Planner, budget: PlannerBudget, time_limit: float, seed: int,
           warm: Sequence[np.ndarray] = ()) -> tuple[PlannedState, list[np.ndarray]]:
    """The centre of the task's initial box, planned with the pilot's larger budget: the state
    and the sequences found on the way, shortest first (every state's warm starts: a longer one
    may reach from a state the shortest does not)."""
    from asap_dsl.sampling import init_box

    lo, hi = init_box(prog.system, planner.task.model.init_box)
    centre = np.where(np.isfinite(lo) & np.isfinite(hi), (lo + hi) / 2, 0.0)
    if budget.pilot < 1:
        return PlannedState(-1, centre, None, "not_found", False), []
    # no polish: the pilot has its own descents and shortening below (on the swimmer's costly
    # rollouts the polish's would spend the pilot's whole time limit before them)
    coarse = replace(budget, hold=max(budget.hold, budget.pilot_hold), polish=0.0)
    pilot = Planner(prog, planner.task_name, coarse, time_limit * budget.pilot, seed)
    start = time.perf_counter()
    until = pilot.now() + time_limit * budget.pilot
    r = pilot.plan(centre, -1, warm=warm)
    spent = r.rollouts
    if r.steps is None:
        # nothing around "do nothing": local searches from the most promising periodic
        # sequences (strokes, then a glide) until one reaches
        rng = np.random.default_rng([seed, 17])
        starts, used = pilot.ranked_periodic(centre, rng, budget.islands)
        spent += used
        for z0 in starts[: budget.islands]:
            if pilot.now() > until:
                break
            t, z, used = pilot.descend(centre, z0)
            spent += used
            if z is not None:
                r = replace(r, steps=int(t), status="solved", actions=pilot.actions(z[None])[0, : int(t)])
                break
    if r.steps is None:
        return replace(r, rollouts=spent, seconds=time.perf_counter() - start), []
    r2 = pilot.plan(centre, -1, warm=[r.actions], iterations=budget.iterations * (budget.pilot - 1) or 1)
    spent += r2.rollouts
    if r2.steps is not None and r2.steps < r.steps:
        r = r2
    found, used = pilot.shorten(centre, r.actions, until)
    spent += used
    r = replace(r, steps=len(found[-1]), actions=found[-1], status="solved")
    sequences = [a for a in reversed(found) if len(a)]
    return replace(r, rollouts=spent, seconds=time.perf_counter() - start), sequences


def shortest_sequences(results: Sequence[PlannedState], size: int) -> list[np.ndarray]:
    """The ``size`` shortest sequences found (one per state; ties by index): the exchange, and the
    warm starts one task hands the next."""
    found = sorted((r for r in results if r.steps is not None and r.actions is not None and r.steps > 0),
                   key=lambda r: (r.steps, r.index))
    return [np.asarray(r.actions, float) for r in found[:size]]


# --------------------------------------------------------------------------- consistency
def tighten_planned(prog, reports: Sequence[OracleReport]) -> dict[str, int]:
    """For planner reports of tasks with the same ``asap``, every sequence found for one task
    is replayed under the other (states matched by x0) and adopted where it reaches sooner, as
    :func:`~asap_dsl.backends.oracle.solver.tighten` does for the oracle. Returns, per task,
    how many states improved; each report gets ``extra["tightened"]``."""
    summary: dict[str, int] = {}
    originals = {id(rep): list(rep.results) for rep in reports}
    for rep in reports:
        asap = ir.to_text(prog.task(rep.task).model.asap)
        by_x0 = {np.asarray(r.x0, float).tobytes(): i for i, r in enumerate(rep.results)}
        sources, improved = [], set()
        for other in reports:
            if other is rep or ir.to_text(prog.task(other.task).model.asap) != asap:
                continue
            sources.append(other.task)
            cand = []
            for r in originals[id(other)]:
                i = by_x0.get(np.asarray(r.x0, float).tobytes())
                if i is None or r.steps is None or r.actions is None:
                    continue
                cur = rep.results[i]
                if cur.steps is None or r.steps < cur.steps:
                    cand.append((i, replace(cur, steps=r.steps, actions=r.actions, source=other.task)))
            if not cand:
                continue
            replayed = replay_counted(prog, rep.task, [c for _, c in cand])
            for (i, _), r in zip(cand, replayed):
                cur = rep.results[i]
                if r.verified and (cur.steps is None or r.steps < cur.steps):
                    rep.results[i] = r
                    improved.add(i)
        rep.extra["tightened"] = {"from": sources, "improved_states": len(improved)}
        summary[rep.task] = len(improved)
    return summary
