"""``asap_dsl.backends.compare.paired.compare`` / ``asapc compare``: a sweep of training runs, every run and
every non-RL method judged on the same seeded states (paired), beside the oracle's ceiling, and
the report that shows it (:mod:`.report`, :mod:`.plots`).
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from asap_dsl.rollout import Evaluator
from asap_dsl.processes import Interrupts
from asap_dsl.runfiles import command_line, lock_dir, shown, writing
from asap_dsl.runs import RunDir, RunError, atomic_write_json, json_safe, package_versions, spec_hash
from asap_dsl.runsummary import add_to_summary, read_examples, restore_summaries, save_summary
from asap_dsl.sampling import EVAL_SEED, task_states

from . import phase_plots, plots
from .controllers import lookahead_problem
from .report import REWARD_NAMES, Column, Method, ReportData, references, unique, write
from .sweep import Job, SweepInterrupted, execute, load_result, plan

__all__ = ["CompareResult", "check_lookahead", "check_tolerances", "compare", "robustness_until_reach"]


@dataclass
class CompareResult:
    out_dir: Path
    markdown: Path
    html: Path
    data: ReportData
    results: list[dict]
    seconds: float
    failed: list = field(default_factory=list)  # the runs that could not be used: run, run_dir, error


def _evaluation(prog, task: str, states: np.ndarray, oracle, label: str, controller) -> dict:
    """``controller``'s evaluation on the seeded states, as a run's eval.json holds it."""
    from ..rl.evaluation import summarise

    start = time.perf_counter()
    res = Evaluator(prog, task, states).run(controller)
    return summarise(res, method=label, prog=prog, task=task, seed=EVAL_SEED,
                     tolerances=list(prog.task(task).model.tolerances), oracle=oracle,
                     seconds=time.perf_counter() - start).to_dict()


def _cached_evaluation(path: Path, prog, task: str, states: np.ndarray, oracle, label: str,
                       controller: Callable[[], object]) -> Optional[dict]:
    """A controller's evaluation on the seeded states, read from ``path`` where it was cached,
    else rolled out (``controller()`` builds it; None: nothing to evaluate) and cached there."""
    if path.is_file():
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except ValueError:
            pass
    ctrl = controller()
    if ctrl is None:
        return None
    ev = _evaluation(prog, task, states, oracle, label, ctrl)
    atomic_write_json(path, ev)
    return ev


def _baseline(prog, task: str, kind: str, states: np.ndarray, oracle, cache: Path) -> Optional[dict]:
    """The greedy controller's or the oracle replay's evaluation on the seeded states (cached)."""
    from .controllers import GreedyController, OracleController

    name = f"{spec_hash(prog.source)[:16]}-{task}-{kind}-n{len(states)}"
    if kind == "oracle" and oracle is not None:  # a re-planned or re-solved ceiling is replayed again
        name += "-" + hashlib.sha256(json.dumps(oracle.data.get("states"), default=str).encode()).hexdigest()[:8]

    def controller():
        if kind == "oracle":
            return None if oracle is None else OracleController.from_cache(oracle, prog.system.n_action)
        try:
            return GreedyController(prog, task, budget=25 if prog.system.kind == "simulator" else 125)
        except ValueError:
            return None

    label = "greedy one-step look-ahead" if kind == "greedy" else "oracle action sequences, replayed"
    return _cached_evaluation(cache / f"{name}.json", prog, task, states, oracle, label, controller)


def _lookahead_evaluation(result: dict, prog, task: str, states: np.ndarray, oracle, hold: int,
                          summaries: Optional[str]) -> Optional[dict]:
    """The run's policy refined by the look-ahead (:class:`.controllers.LookaheadController`) on
    the sweep's states: read from the run (:meth:`RunDir.read_lookahead`, restored with its
    summary), else made from its model, kept in the run and added to its summary under
    ``summaries``; None for a summary without its model or that evaluation."""
    from ..rl.evaluation import load_run
    from .controllers import LookaheadController

    run, manifest = RunDir(result["run_dir"]), result["manifest"]
    with run.acquire(exclusive=False):
        kept = run.read_lookahead(hold, len(states), manifest)
    if kept is not None or not result.get("model", True):
        return kept
    job = result["job"]
    label = f"{job['algo']} ({job['reward']} reward, seed {job['seed']}), look-ahead {hold}"
    refined = LookaheadController(prog, load_run(result["run_dir"]).controller(), task, hold=hold)
    ev = json.loads(json.dumps(json_safe(_evaluation(prog, task, states, oracle, label, refined))))
    with run.acquire(exclusive=True):
        path = run.write_lookahead(ev, hold, len(states), manifest["model"]["sha256"])
    if summaries is not None:
        add_to_summary(run.path, summaries, path.name)
    return ev


def _prefix_evaluation(ev: dict, prog, task: str, states: np.ndarray, oracle) -> Optional[dict]:
    """An evaluation on more states of the evaluation seed, cut to the sweep's ``states`` where those
    are its first (the seeded draw is one stream, except where a state was redrawn: checked); None
    where they are not. How a summary (no model) serves a report on fewer states: the swimmer's
    runs are evaluated on 1000 states, its report on the planner's 200."""
    from asap_dsl.rollout import RolloutResult

    from ..rl.evaluation import summarise

    n = len(states)
    per = ev.get("per_state") or {}
    if not (ev.get("seed") == EVAL_SEED and isinstance(ev.get("episodes"), int) and ev["episodes"] > n
            and len(per.get("t_reach") or []) == ev["episodes"] and len(per.get("end_reason") or []) == ev["episodes"]):
        return None
    model = prog.task(task).model
    if not np.array_equal(task_states(prog.system, model, ev["episodes"], seed=EVAL_SEED)[:n], states):
        return None
    t = np.array([np.inf if x is None else float(x) for x in per["t_reach"][:n]])
    res = RolloutResult(states, t, np.array(per["end_reason"][:n]), np.zeros(n, np.int64), np.zeros(n),
                        model.deadline)
    cut = summarise(res, method=ev.get("method", ""), prog=prog, task=task, seed=EVAL_SEED,
                    tolerances=list(ev.get("tolerances") or model.tolerances), oracle=oracle,
                    seconds=float(ev.get("seconds") or 0.0)).to_dict()
    cut["notes"] = list(ev.get("notes") or []) + [f"the first {n:,} of the run's {ev['episodes']:,} evaluation states"]
    return cut


def _run_evaluation(result: dict, episodes: int, oracle, prog=None, task: Optional[str] = None,
                    states: Optional[np.ndarray] = None) -> dict:
    """The run's evaluation on the sweep's states: its final one when it used them (or their
    superset, cut: :func:`_prefix_evaluation`), else a new one; the ASAP gap against the oracle
    recomputed (the run may have finished before the oracle)."""
    from asap_dsl.stats import asap_gap

    ev = result["evaluation"]
    if not (ev.get("episodes") == episodes and ev.get("seed") == EVAL_SEED and "per_state" in ev):
        cut = None if states is None else _prefix_evaluation(ev, prog, task, states, oracle)
        if cut is not None:
            ev = cut
        elif not result.get("model", True):
            raise RunError(f"its summary's evaluation is on {ev.get('episodes')} states of seed {ev.get('seed')}, "
                           f"not {episodes} of seed {EVAL_SEED}, and its model was not kept: train it again")
        else:
            from ..rl.evaluation import evaluate

            ev = json.loads(json.dumps(json_safe(evaluate(result["run_dir"], episodes=episodes, oracle="cache",
                                                          write=False).to_dict())))
    if oracle is not None:
        t = np.array([np.inf if x is None else float(x) for x in ev["per_state"]["t_reach"]])
        ev["gap"] = asap_gap(t, oracle.steps)
    return ev


#: The example episodes of a report: its first this many evaluation states.
EXAMPLE_STATES = 4


def _policy_controller(result: dict, n_action: int):
    """The run's policy, or (a summary without its model) its recorded example actions replayed;
    None when it has neither."""
    from ..rl.evaluation import load_run
    from .controllers import OracleController

    if result.get("model", True):
        return load_run(result["run_dir"]).controller()
    run = RunDir(result["run_dir"])
    with run.acquire(exclusive=False):
        recorded = read_examples(run, run.read_manifest())
    if recorded is None:
        return None
    states, actions = recorded
    return OracleController(states, actions, n_action)


def _recorded_examples(result: dict, episodes: int) -> dict:
    """The run's policy rolled out from the report's example states, its actions recorded (what a
    summary keeps in place of the model)."""
    from ..rl.evaluation import load_run

    loaded = load_run(result["run_dir"])
    prog, task = loaded.program, loaded.config.task
    states = task_states(prog.system, prog.task(task).model, episodes, seed=EVAL_SEED)[:EXAMPLE_STATES]
    res = Evaluator(prog, task, states).run(loaded.controller(), record=True)
    return {"states": states, "actions": res.actions}


def _examples(prog, task: str, result: dict, oracle, states: np.ndarray, title: str,
              n: int = EXAMPLE_STATES) -> Optional[dict]:
    """``n`` example episodes of the run's policy and of the oracle's replayed sequences from the
    first ``n`` of the sweep's states (the oracle's own, so that its sequences are found): the
    robustness of ``asap`` along them, and the paths in the state space (``phase``)."""
    from .phase_plots import example

    controller = _policy_controller(result, prog.system.n_action)
    if controller is None:
        return None
    asap = prog.task(task).asap
    j = result["job"]
    label = f"{REWARD_NAMES.get(j['reward'], j['reward'])} ({j['algo']})"
    phase, res, ores = example(prog, task, states[:n], controller, oracle, title=title, label=label)

    def reached(res):
        return [bool(np.isfinite(t)) for t in res.t_reach]

    return {"policy": robustness_until_reach(asap, res), "label": label, "phase": phase,
            "oracle": None if ores is None else robustness_until_reach(asap, ores),
            "policy_reached": reached(res), "oracle_reached": None if ores is None else reached(ores)}


def robustness_until_reach(asap, res) -> list[list[float]]:
    """The robustness of ``asap`` along each recorded episode of ``res``, up to its reach point
    (or its end where it never reached): after it the task is done, and an oracle's replay plays
    zeros once its sequence ends, which would draw a drift no controller chose."""
    ends = [int(t) if np.isfinite(t) else int(e) for t, e in zip(res.t_reach, res.end_step)]
    return [asap.robustness(res.trajectories[i, : ends[i] + 1]).tolist() for i in range(res.episodes)]


def compare(specs: Sequence[str], *, tasks: Optional[Sequence[str]] = None,
            rewards: Sequence[str] = ("asap", "rho", "distance"), algos: Sequence[str] = ("sac",), seeds: int = 3,
            steps: Optional[int] = None, preset: str = "default", workers: int = 1, ray: Optional[str] = None,
            out: str = "reports/compare", episodes: int = 1000,
            on_event: Optional[Callable[[str, Job, Optional[dict]], None]] = None,
            oracle_workers: Optional[int] = None, ray_timeout: float = 30.0,
            engine: Optional[str] = None, table2_tolerances: Sequence[int] = (),
            on_oracle: Optional[Callable[[str, int, int], None]] = None,
            summaries: Optional[str] = None, lookahead: int = 0, imitation: Optional[float] = None,
            search_iterations: Optional[int] = None) -> CompareResult:
    """Train what is missing, evaluate everything on the same states, write the report.
    ``engine`` (sbx or sb3) trains every run; None: the preset's engine where it has the algorithm.
    ``table2_tolerances``: Table 2 within these steps too, beside every tolerance of the spec (the
    paper's Table 2 tolerance: 30 DC motor, 20 bicycle and attitude, 50 swimmer); each at most
    every task's deadline (:func:`check_tolerances`, ``ValueError``). ``on_oracle(column, solved,
    states)`` is told when the oracle starts computing a column's minima (solved 0: they were not
    cached; minutes for a thousand states) and when it has them all. ``summaries``: a directory of
    run summaries (:mod:`asap_dsl.runsummary`) copied into the runs before the sweep plans (read
    back, not trained) and written there as each run finishes, with its policy's recorded example
    actions for the run the report draws its examples from: a sweep that outlives its machine.
    ``lookahead``: Table 1 also shows the first reward's and algorithm's policies refined by a
    look-ahead holding actions up to this many steps (:class:`.controllers.LookaheadController`;
    0: not). ``imitation`` and ``search_iterations``: every run's, as ``asapc train``'s flags (None:
    the preset's).

    Holds ``out``'s exclusive lock throughout (a second compare on it is refused, naming the
    first). Runs that cannot be used (failed, damaged) are left out of the tables, named in the
    report's notes and in ``CompareResult.failed``. Raises
    :class:`~asap_dsl.backends.compare.sweep.SweepInterrupted` when Ctrl-C or SIGTERM stops any
    phase (the finished runs stay, running ones are checkpointed: the same call continues), and
    :class:`asap_dsl.runs.RunError` for an ``out`` that cannot be used.
    """
    start = time.perf_counter()
    if table2_tolerances or lookahead:
        jobs = plan(specs, tasks, list(rewards), list(algos), 1, preset, steps, engine, imitation=imitation,
                    search_iterations=search_iterations)
        check_tolerances(jobs, table2_tolerances)
        check_lookahead(jobs, lookahead)
    out_dir = Path(out).expanduser().resolve()
    if out_dir.exists() and not out_dir.is_dir():
        raise RunError(f"--out {shown(out_dir)} is a file; compare writes a directory (its report and runs)")
    with writing(out_dir):
        out_dir.mkdir(parents=True, exist_ok=True)
    phase = ["planning"]
    results: list[dict] = []
    # One sweep per --out at a time; Ctrl-C and SIGTERM stop every phase (the sweep's trainings checkpoint).
    with lock_dir(out_dir, exclusive=True, wait_hint="wait for that compare to finish, or give another --out"), \
            Interrupts(raise_outside=True):
        try:
            return _compare(specs, tasks, rewards, algos, seeds, steps, preset, workers, ray, out_dir, episodes,
                            on_event, oracle_workers, ray_timeout, start, phase, results, engine,
                            sorted({int(T) for T in table2_tolerances}, reverse=True), on_oracle, summaries,
                            int(lookahead), imitation, search_iterations)
        except KeyboardInterrupt:
            raise SweepInterrupted(results, phase[0]) from None
        except SweepInterrupted as err:
            err.phase = phase[0]
            raise


def _keeping_summaries(on_event, summaries: str, algo: str, reward: str, episodes: int, errors: list):
    """``on_event`` that also writes each finished run's summary into ``summaries`` (for seed 0 of
    ``reward`` with ``algo``, the report's example run, with its policy's recorded examples); a
    summary that cannot be written is said in ``errors`` (the report's notes), the sweep goes on."""
    def told(kind: str, job: Optional[Job], result: Optional[dict]) -> None:
        if kind == "done" and result and result.get("status") == "finished" and result.get("model", True):
            try:
                example = job.algo == algo and job.reward == reward and job.seed == 0
                save_summary(result["run_dir"], summaries,
                             examples=_recorded_examples(result, episodes) if example else None)
            except RunError as err:
                errors.append(str(err))
        if on_event is not None:
            on_event(kind, job, result)
    return told


def run_phases(manifest: dict) -> str:
    """What a run did beyond its learner, in a few words, from its manifest: the oracle's (or the
    planner's) paths it was given and whether its actor imitated them, and the policy search."""
    cfg = manifest.get("config") or {}
    parts = []
    for key, when in (("demonstrations", "from the start"), ("late_demonstrations", "on a stall")):
        found = manifest.get(key)
        for d in (found if isinstance(found, list) else [found] if found else []):
            if isinstance(d, dict) and d.get("added"):
                parts.append(f"{d.get('searcher', 'oracle')}'s paths of {int(d['added']):,} states {when}")
    if parts and float(cfg.get("imitation") or 0.0) > 0:
        parts[0] += f", imitated (weight {float(cfg['imitation']):g})"
    search = manifest.get("policy_search")
    if isinstance(search, dict):
        kept = search.get("kept_iteration")
        its = int(search.get("iterations") or 0)
        gain = search.get("action_gain", 1.0)
        gained = f", actions with gain {gain:g}" if isinstance(gain, (int, float)) and gain != 1.0 else ""
        parts.append(f"search: iteration {int(kept):,} of {its:,} kept{gained}" if kept is not None
                     else f"search: {its:,} iterations, the learner's model kept")
    return "; ".join(parts) or "the learner alone"


def _status(result: dict) -> str:
    """What this sweep did with a run: ``trained now``, ``resumed`` (from an interrupted sweep's
    checkpoint) or ``reused`` (finished before)."""
    if not result["trained_now"]:
        return "reused"
    return "resumed" if result.get("resumed") else "trained now"


def _oracle(prog, task: str, episodes: int, workers: Optional[int], name: str, on_oracle):
    """The oracle's minima on the sweep's states (cached, or computed now and cached); a black box's
    planner only where ``asapc oracle`` cached it. ``on_oracle`` hears of a computation."""
    from ..oracle.cache import oracle_for

    tell = on_oracle or (lambda *args: None)
    solved = [0]

    def progress(k: int) -> None:
        solved[0] += k
        tell(name, solved[0], episodes)

    return oracle_for(prog, task, EVAL_SEED, episodes, workers=workers, progress=progress,
                      started=lambda: tell(name, 0, episodes))


def _deadlines(jobs: Sequence[Job]) -> dict[tuple[str, str], int]:
    """Each of the sweep's (spec, task) and its deadline, each spec loaded once."""
    import asap_dsl

    progs: dict = {}
    out = {}
    for job in jobs:
        if job.spec not in progs:
            progs[job.spec] = asap_dsl.load(job.spec)
        out[(job.spec, job.task)] = progs[job.spec].task(job.task).model.deadline
    return out


def check_tolerances(jobs: Sequence[Job], tolerances: Sequence[int]) -> None:
    """``ValueError`` (one sentence) for a Table 2 tolerance under 1 step or beyond the deadline of
    one of the sweep's tasks (an episode ends at its deadline: nothing is measured beyond it)."""
    for T in tolerances:
        if int(T) < 1:
            raise ValueError(f"a tolerance is at least 1 step, got {T}")
    if not tolerances:
        return
    for (spec, task), deadline in _deadlines(jobs).items():
        for T in tolerances:
            if int(T) > deadline:
                raise ValueError(f"tolerance {T} is beyond the deadline of {Path(spec).stem} {task} "
                                 f"({deadline} steps: its episodes end there)")


def check_lookahead(jobs: Sequence[Job], hold: int) -> None:
    """``ValueError`` (one sentence) for a look-ahead that holds an action longer than the deadline
    of one of the sweep's tasks (checked before anything trains)."""
    if int(hold) < 0:
        raise ValueError(f"the look-ahead holds an action for 0 (none) or more steps, got {hold}")
    if not hold:
        return
    for (spec, task), deadline in _deadlines(jobs).items():
        if int(hold) > deadline:
            raise ValueError(f"--lookahead {hold} is beyond the deadline of {Path(spec).stem} {task} "
                             f"({deadline} steps: an action is held for at most that)")


def column_labels(specs: Sequence[str]) -> dict[str, str]:
    """A name per spec for the report's columns: its path's shortest suffix (without ``.asap``)
    that no other spec of the sweep ends with (``a/di`` and ``b/di`` for two ``di.asap``)."""
    parts = {s: Path(s).resolve().with_suffix("").parts for s in specs}
    out = {}
    for s, mine in parts.items():
        k = 1
        while k < len(mine) and any(o[-k:] == mine[-k:] for t, o in parts.items() if t != s):
            k += 1
        out[s] = "/".join(mine[-k:])
    return out


def _compare(specs, tasks, rewards, algos, seeds, steps, preset, workers, ray, out_dir: Path, episodes, on_event,
             oracle_workers, ray_timeout, start, phase: list, results: list, engine=None,
             table2_tolerances: Sequence[int] = (), on_oracle=None, summaries: Optional[str] = None,
             lookahead: int = 0, imitation: Optional[float] = None,
             search_iterations: Optional[int] = None) -> CompareResult:
    import asap_dsl

    jobs = plan(specs, tasks, list(rewards), list(algos), seeds, preset, steps, engine, imitation=imitation,
                search_iterations=search_iterations)
    labels = column_labels(sorted({j.spec for j in jobs}))
    phase[0] = "training"
    kept_errors: list[str] = []
    if summaries is not None:
        restore_summaries(summaries, out_dir / "runs")
        on_event = _keeping_summaries(on_event, summaries, algos[0], rewards[0], episodes, kept_errors)
    results[:] = execute(jobs, str(out_dir / "runs"), workers=workers, ray_address=ray, on_event=on_event,
                         ray_timeout=ray_timeout)
    phase[0] = "the evaluations"

    def what(r: dict) -> str:
        j = r["job"]
        return f"{labels.get(j['spec'], Path(j['spec']).stem)} {j['task']} {j['algo']} {j['reward']} seed {j['seed']}"

    failed = [{"run": what(r), "run_dir": r.get("run_dir"), "error": r.get("error")}
              for r in results if r["status"] == "failed"]
    notes = [f"{what(r)}: trained again ({r['note']})" for r in results if r.get("note")]
    loaded = []
    for r in results:
        if r["status"] != "finished":
            continue
        try:
            loaded.append(load_result(r))
        except RunError as err:
            failed.append({"run": what(r), "run_dir": r.get("run_dir"), "error": str(err)})
    notes += [f"{f['run']}: not used ({f['error']})" for f in failed]
    notes += [f"summary not kept: {e}" for e in kept_errors]
    notes += [f"{what(r)}: training curves left out ({r['curves_error']})" for r in loaded if r.get("curves_error")]

    columns: list[Column] = []
    table1 = {r: Method(f"{r}/{algos[0]}", f"{REWARD_NAMES.get(r, r)} ({algos[0]})", "rl") for r in rewards}
    table2 = {a: Method(f"{rewards[0]}/{a}", f"{REWARD_NAMES.get(rewards[0], rewards[0])} ({a})", "rl") for a in algos}
    first_label = f"{REWARD_NAMES.get(rewards[0], rewards[0])} ({algos[0]})"
    refined = Method(f"{rewards[0]}/{algos[0]}+lookahead", f"{first_label} + look-ahead {lookahead}",
                     "lookahead")
    greedy = Method("greedy", "greedy look-ahead", "greedy")
    replay = Method("oracle-replay", "oracle, replayed", "oracle")
    examples, curves = {}, {}
    seen = set()
    for job in jobs:
        key = (job.spec, job.task)
        if key in seen:
            continue
        seen.add(key)
        prog = asap_dsl.load(job.spec)
        tm = prog.task(job.task).model
        col = Column(job.spec, job.task, list(tm.tolerances), tm.deadline, label=labels.get(job.spec),
                     black_box=prog.system.kind == "simulator")
        phase[0] = "the oracle"
        oracle = _oracle(prog, job.task, episodes, oracle_workers, col.name, on_oracle)
        phase[0] = "the evaluations"
        if oracle is not None:
            col.ceiling = {T: oracle.ceiling(T) for T in sorted({*tm.tolerances, *table2_tolerances}) if T <= tm.deadline}
            col.bound = oracle.bound
            col.oracle_steps = [None if not np.isfinite(x) else int(x) for x in oracle.steps]
        elif prog.system.kind == "simulator":  # compare never plans: minutes per hundred states
            mine = {j.task for j in jobs if j.spec == job.spec}  # several: planned together, warm-started, tightened
            cmd = command_line(["asapc", "oracle", job.spec] + (["--task", job.task] if len(mine) == 1 else [])
                               + ["--episodes", str(episodes)])
            note = (f"{col.name if len(mine) == 1 else col.label}: no ceiling: the planner's achievable steps are "
                    f"not cached for these {episodes:,} states; `{cmd}` plans them (minutes per hundred states), "
                    "then the same compare reads them")
            if note not in notes:
                notes.append(note)
        columns.append(col)
        states = task_states(prog.system, tm, episodes, seed=EVAL_SEED)
        for method, kind in ((greedy, "greedy"), (replay, "oracle")):
            ev = _baseline(prog, job.task, kind, states, oracle, out_dir / "methods")
            if ev is not None:
                method.evaluations.setdefault(col.name, []).append(ev)
            if kind == "oracle" and ev is not None:  # the rollout must reproduce the oracle's minima
                for row in ev["rows"]:
                    want = col.ceiling[row["tolerance"]]["count"]
                    if row["count"] != want:
                        notes.append(f"{col.name}: the oracle's action sequences, replayed by the rollout, succeed "
                                     f"on {row['count']} states within {row['tolerance']} where the oracle reports {want}")
        mine = [r for r in loaded if (r["job"]["spec"], r["job"]["task"]) == key]
        why = lookahead_problem(prog, job.task) if lookahead else None
        if why is not None:
            notes.append(f"{col.name}: no look-ahead row ({why})")
        refine = bool(lookahead) and why is None
        for r in sorted(mine, key=lambda r: r["job"]["seed"]):
            j = r["job"]
            try:
                ev = _run_evaluation(r, episodes, oracle, prog, job.task, states)
            except RunError as err:  # a summary evaluated on other states: nothing to evaluate again
                notes.append(f"{what(r)}: not used ({err})")
                continue
            if j["algo"] == algos[0] and j["reward"] in table1:
                table1[j["reward"]].evaluations.setdefault(col.name, []).append(ev)
            if refine and j["algo"] == algos[0] and j["reward"] == rewards[0]:
                better = _lookahead_evaluation(r, prog, job.task, states, oracle, lookahead, summaries)
                if better is not None:
                    refined.evaluations.setdefault(col.name, []).append(better)
                else:  # read back from a summary: its policy is gone, its refinement was never kept
                    notes.append(f"{what(r)}: not in the look-ahead row (its summary kept no model; "
                                 f"remove the summary to train it again)")
            if j["reward"] == rewards[0] and j["algo"] in table2:
                table2[j["algo"]].evaluations.setdefault(col.name, []).append(ev)
            curves.setdefault(col.name, []).append((f"{REWARD_NAMES.get(j['reward'], j['reward'])} ({j['algo']})",
                                                    r["curves"]))
        first = [r for r in mine if r["job"]["algo"] == algos[0] and r["job"]["reward"] == rewards[0]]
        for r in sorted(first, key=lambda r: r["job"]["seed"]):  # the first with a policy or its recorded examples
            ex = _examples(prog, job.task, r, oracle, states, col.name)
            if ex is not None:
                examples[col.name] = ex
                break

    replay.label = f"{references(columns)}, replayed"
    t1 = list(table1.values()) + ([refined] if refined.evaluations else []) + [greedy]
    t2 = list(table2.values()) if len(algos) > 1 else []
    runs = [{"label": f"{labels[r['job']['spec']]} {r['job']['task']} {r['job']['algo']} {r['job']['reward']}",
             "spec_hash": r["manifest"]["spec_hash"], "seed": r["job"]["seed"], "preset": Job(**r["job"]).training(),
             "phases": run_phases(r["manifest"]), "steps": r["steps"], "seconds": r["seconds"], "status": _status(r)}
            for r in loaded]
    phase[0] = "the report"
    data = ReportData(title="ASAP-Phi comparison: " + ", ".join(sorted(set(labels.values()))),
                      columns=columns, table1=t1, table2=t2, runs=runs, notes=notes, versions=package_versions(),
                      table2_tolerances=list(table2_tolerances))
    figures = {
        "state_space": phase_plots.state_space([ex["phase"] for ex in examples.values()]),
        "success_vs_tolerance": plots.success_vs_tolerance(columns, unique(t1 + t2) + [replay]),
        "steps_vs_oracle": plots.steps_vs_oracle(columns, t1[0]),
        "trajectories": plots.trajectories(columns, examples),
        "training_curves": plots.training_curves(columns, curves),
    }
    data.plots = {k: v for k, v in figures.items() if v is not None}
    data.seconds = time.perf_counter() - start
    paths = write(out_dir, data)
    atomic_write_json(out_dir / "sweep.json", {"jobs": [r for r in results], "failed": failed, "seconds": data.seconds})
    return CompareResult(out_dir, paths["markdown"], paths["html"], data, results, data.seconds, failed)
