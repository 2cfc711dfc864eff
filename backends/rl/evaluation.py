"""Evaluating a trained run: ``asap_dsl.evaluate`` and ``asapc eval``.

The run's best model acts deterministically on the seeded evaluation states (seed 2024 by
default, the states the oracle and every other method get) in one batched rollout
(:mod:`asap_dsl.rollout`). The result: the success rate at each tolerance with its 95% Wilson
interval, beside the oracle's ceiling on the same states where the dynamics are known; steps-to-
reach statistics; failures by end reason; and the ASAP gap.

Loading a model unpickles it, so a model is loaded only from the run directory the user names,
after checking its manifest and that its spec is the one it was trained on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np

from asap_dsl.limits import LIMITS, check_batch
from asap_dsl.diagnostics import SpecError
from asap_dsl.formatting import percent, steps_text
from asap_dsl.program import Program, loads, read_source
from asap_dsl.rollout import Evaluator, RolloutResult
from asap_dsl.runs import RunDir, RunError, RunWriteError, command_line, spec_hash
from asap_dsl.sampling import EVAL_SEED, task_states
from asap_dsl.stats import asap_gap, rate, steps_summary

from .config import ConfigError, TrainConfig
from .engines import get_engine
from .sb3 import PolicyController, Scaling

__all__ = ["Evaluation", "evaluate", "load_run", "summarise"]



@dataclass
class Evaluation:
    """A controller's results on seeded initial states, beside the oracle's where known."""

    method: str
    spec_file: str
    spec_hash: str
    task: str
    seed: int
    episodes: int
    tolerances: list[int]
    rows: list[dict]             # per tolerance: tolerance, count, states, rate, ci95, ceiling (or None)
    steps: dict                  # steps to reach (states that reached within the deadline)
    failures: dict               # episodes that failed before reaching, by reason
    gap: Optional[dict]          # the ASAP gap against the oracle (None without an oracle)
    oracle: Optional[dict]       # label and source of the ceiling (None: unknown, with reason)
    seconds: float
    per_state: dict = field(default_factory=dict)  # t_reach and oracle minimum per state
    notes: list[str] = field(default_factory=list)

    def to_dict(self, per_state: bool = True) -> dict:
        d = {k: getattr(self, k) for k in ("method", "spec_file", "spec_hash", "task", "seed", "episodes",
                                             "tolerances", "rows", "steps", "failures", "gap", "oracle", "seconds",
                                             "notes")}
        if per_state:
            d["per_state"] = self.per_state
        return d

    def rate(self, tolerance: int) -> Optional[float]:
        for r in self.rows:
            if r["tolerance"] == tolerance:
                return r["rate"]
        raise KeyError(f"tolerance {tolerance} was not evaluated (evaluated: {self.tolerances})")

    def render(self) -> str:
        """The table a user reads: rate, interval and ceiling per tolerance, then the rest."""
        def pct(x):  # a column five wide, and its percent sign
            return percent(x, 5, missing="  n/a ")

        lines = [f"{self.spec_file}: task {self.task}, {self.method}: {self.episodes} initial states (seed {self.seed}), "
                 f"deterministic policy, {self.seconds:.2f} s"]
        oracle = self.oracle or {}
        bound = oracle.get("bound")
        head = f"  {'within':>6}  {'success':>7}  {'95% CI':<16}"
        # The planner's rates are achieved, not a limit: a policy may beat them.
        achievable = oracle.get("label") == "achievable"
        if bound:
            head += f"  {bound:<16}  {'95% CI':<16}  {'below planner' if achievable else 'below ceiling':>13}"
        lines += ["", head]
        for r in self.rows:
            lo, hi = r["ci95"]
            line = f"  {r['tolerance']:>6}  {pct(r['rate'])}  [{pct(lo)}, {pct(hi)}]"
            c = r.get("ceiling")
            if c:
                clo, chi = c["ci95"]
                own = r.get("rate_on_ceiling_states", r["rate"])
                line += f"  {pct(c['rate']):<16}  [{pct(clo)}, {pct(chi)}]  {100 * (c['rate'] - own):>10.1f} pts"
            lines.append(line)
        if not bound:
            lines.append(f"  ceiling: {oracle.get('reason', 'unknown')}")
        elif oracle.get("states", self.episodes) < self.episodes:
            who = "the planner's (achievable)" if achievable else "the oracle's"
            lines.append(f"  ceiling: {who} on the first {oracle['states']:,} of these {self.episodes:,} states, "
                         f"and the distance below it this controller's rate on those states "
                         f"(cached; `asapc oracle {self.spec_file} --task {self.task} --seed {self.seed} --episodes "
                         f"{self.episodes}` computes all)")
        s = self.steps
        lines.append("")
        if s.get("reached"):
            lines.append(f"  steps to reach ({s['reached']} states): {steps_text(s)}")
        else:
            lines.append("  steps to reach: no state reached the goal")
        f = self.failures
        lines.append(f"  not reached: {sum(f.values())} (avoid {f['avoid']}, left the state space {f['out_of_bounds']}, "
                     f"non-finite {f['non_finite']}, deadline passed {f['not_reached']})")
        g = self.gap
        if g is not None:
            if g.get("gap") is None:
                lines.append(f"  ASAP gap: n/a ({g.get('reason')})")
            else:
                lines.append(f"  ASAP gap: {g['gap']:.3f} (median of steps / oracle minimum over {g['states']} states "
                             f"both reach; 75% {g['p75']:.3f}; {percent(g['share_optimal'])} in the minimum)")
        for n in self.notes:
            lines.append(f"  note: {n}")
        return "\n".join(lines)


def summarise(result: RolloutResult, *, method: str, prog: Program, task: str, seed: int,
              tolerances: Sequence[int], oracle=None, seconds: float = 0.0) -> Evaluation:
    """An :class:`Evaluation` from a rollout (any controller) and the cached oracle (or None)."""
    covered = oracle.count if oracle is not None else 0  # a cached oracle on the first of these states
    rows = []
    for T in tolerances:
        ok = result.successes(T)
        row = {"tolerance": int(T), **rate(ok)}
        row["ceiling"] = oracle.ceiling(T) if oracle is not None else None
        if 0 < covered < result.episodes:  # the distance to a ceiling is measured on the states it covers
            row["rate_on_ceiling_states"] = rate(ok[:covered])["rate"]
        rows.append(row)
    reached = result.t_reach[np.isfinite(result.t_reach)]
    gap = asap_gap(result.t_reach[:covered], oracle.steps) if oracle is not None else None
    if oracle is not None:
        info = {"bound": oracle.bound, "label": oracle.label, "seconds": oracle.seconds, "states": covered}
    elif prog.system.kind == "simulator":
        info = {"reason": "not computed for this black box (`asapc oracle` plans through the simulator: planner (achievable))"}
    else:
        info = {"reason": f"not computed for these {result.episodes:,} states (`asapc oracle {prog.file} --task {task} "
                          f"--seed {seed} --episodes {result.episodes}` computes it; so does `asapc eval` without "
                          "--no-oracle)"}
    per_state = {"t_reach": [None if not np.isfinite(x) else int(x) for x in result.t_reach],
                 "end_reason": list(result.end_reason)}
    if oracle is not None:
        per_state["oracle_steps"] = [None if not np.isfinite(x) else int(x) for x in oracle.steps]
    return Evaluation(method, prog.file, spec_hash(prog.source), task, int(seed), result.episodes,
                      [int(t) for t in tolerances], rows, steps_summary(reached), result.failures(), gap, info,
                      round(seconds, 3), per_state)


# ------------------------------------------------------------------------------------ runs
@dataclass
class LoadedRun:
    run: RunDir
    manifest: dict
    config: TrainConfig
    program: Program
    model: Any
    scaling: Scaling
    model_file: Optional[Path] = None  # the model loaded, checked against the manifest's record

    def controller(self) -> PolicyController:
        return PolicyController(self.model, self.scaling)


def load_run(path: Union[str, Path, RunDir], spec: Union[str, Path, None] = None) -> LoadedRun:
    """Open a run directory for evaluation: its manifest, its spec (checked by hash), its model
    (checked against the sha256 the manifest recorded when it was written).

    ``spec``: evaluate against this spec file, which must be the one the run was trained on. By
    default the run's own copy is used, and the original file, if it still exists at the recorded
    path, must not have changed. The run's shared lock is held while it is read (a
    :class:`RunDir` already locked is read under its lock). Raises :class:`RunError` with one
    sentence (:class:`asap_dsl.runs.RunBusy` while another process trains it).
    """
    run = path if isinstance(path, RunDir) else RunDir(path)
    owned = run.lock is None
    run.acquire(exclusive=False)
    try:
        return _load_run(run, spec)
    finally:
        if owned:
            run.release()


def _load_run(run: RunDir, spec: Union[str, Path, None]) -> LoadedRun:
    manifest = run.read_manifest()
    try:
        config = TrainConfig.from_dict(manifest["config"])
    except (ConfigError, TypeError) as err:
        raise RunError(f"{run.manifest_path}: unusable configuration ({err})") from None
    source = run.read_spec()
    trained = manifest["spec_hash"]
    if spec is not None:
        other = read_source(spec)
        if spec_hash(other) != trained:
            raise RunError(f"{run.path} was trained on another spec than {spec} "
                           f"(hash {trained[:12]} there, {spec_hash(other)[:12]} here)")
    else:
        original = Path(manifest.get("spec_file", ""))
        if original.is_file():
            try:
                current = read_source(original)
            except SpecError:
                current = None
            if current is not None and spec_hash(current) != trained:
                raise RunError(f"{original} has changed since {run.path} was trained on it; evaluate the run "
                               f"against its own copy with `{command_line(['asapc', 'eval', str(run.path), '--spec', str(run.spec_path)])}`, "
                               "or train a new run")
    prog = loads(source, manifest.get("spec_file") or str(run.spec_path))
    if config.task not in prog.tasks:
        raise RunError(f"{run.path}: its task '{config.task}' is not in its spec")
    model_path = run.model_file(manifest)
    try:
        model = get_engine(config.engine).load(config.algo, model_path)
    except Exception as err:  # noqa: BLE001 — a damaged or foreign zip: one line, not a trace
        raise RunError(f"{model_path}: cannot load the model ({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})") from None
    try:
        # the kept model's action gain (the policy search's choice; 1 for the learner's model)
        gain = (manifest.get("best") or {}).get("action_gain", 1.0)
        if isinstance(gain, bool) or not isinstance(gain, (int, float)):
            raise ValueError(f"its best model's action_gain is {gain!r}, not a number")
        scaling = Scaling.for_run(prog.system, config, prog.task(config.task).model.init_box, gain=float(gain))
    except ValueError as err:  # a manifest edited by hand
        raise RunError(f"{run.manifest_path}: damaged manifest ({err})") from None
    expected = prog.system.n_state + int("time" in prog.task(config.task).model.observe)  # the env's observation
    if tuple(model.observation_space.shape) != (expected,):
        raise RunError(f"{model_path}: the model observes {model.observation_space.shape[0]} values, "
                       f"the task {expected}: it belongs to another run")
    return LoadedRun(run, manifest, config, prog, model, scaling, model_path)


def evaluate(run: Union[str, Path, RunDir], *, episodes: int = 1000, tolerances: Optional[Sequence[int]] = None,
             seed: int = EVAL_SEED, spec: Union[str, Path, None] = None, oracle: str = "auto",
             workers: Optional[int] = None, write: Optional[bool] = None,
             progress: Optional[Callable[[int], None]] = None,
             started: Optional[Callable[[], None]] = None, lookahead: int = 0,
             refining: Optional[Callable[[int, int, int], None]] = None) -> Evaluation:
    """Evaluate a run's best model, acting deterministically, on ``episodes`` seeded initial states.

    :param run: the run directory (written by :func:`asap_dsl.backends.rl.training.train`).
    :param episodes: how many initial states, drawn from the task's initial box.
    :param tolerances: the step counts success is judged within (default: the task's).
    :param seed: the seed of the states (default 2024, the states the oracle and every other
        method get).
    :param spec: evaluate against this spec file, which must be the one the run was trained on
        (default: the run's own copy, the original checked unchanged where it still exists).
    :param oracle: the ceiling beside the rates: ``auto`` (the cached one, computed first where
        the dynamics are known), ``cache`` (only a cached one) or ``off``. A cached oracle on
        more states of the seed counts where these are its first, one on fewer where its states
        are the first of these (the ceiling is then said to cover those).
    :param workers: processes for computing the oracle (default: one per available core).
    :param write: write the result to the run's ``eval.json`` (default: when it is the run's own
        evaluation: its episode count, seed 2024 and the task's tolerances).
    :param progress: told of the oracle's states solved while it computes (``progress(k)``);
        ``started()`` once before it starts (neither when the ceiling is cached).
    :param lookahead: 0 for the policy alone; N for the policy refined on the spec's simulator by
        candidate actions held for up to N steps, the policy after them
        (:class:`~asap_dsl.backends.compare.LookaheadController`; never written to ``eval.json``,
        which is the policy's own evaluation).
    :param refining: with ``lookahead``, told after each step ``refining(step, deadline, reached)``:
        the states whose refined choice has reached ``asap`` by then.
    :return: success rates with their intervals and ceilings, steps to reach, failures, ASAP gap.
    :raises asap_dsl.runs.RunError: the run cannot be evaluated (one sentence); a failed write of
        ``eval.json`` is :class:`~asap_dsl.runs.RunWriteError` with the evaluation as ``.evaluation``.
    :raises ValueError: an argument out of range (one sentence).
    """
    if oracle not in ("auto", "cache", "off"):
        raise ValueError(f"oracle must be auto, cache or off; got {oracle!r}")
    if not 1 <= int(episodes) <= LIMITS.episodes:
        raise ValueError(f"episodes must be between 1 and {LIMITS.episodes:,}; got {episodes}")
    if seed < 0:
        raise ValueError(f"the seed must be 0 or more; got {seed}")
    run_dir = run if isinstance(run, RunDir) else RunDir(run)
    owned = run_dir.lock is None
    run_dir.acquire(exclusive=False)  # held until eval.json is written: nobody retrains it meanwhile
    try:
        return _evaluate(load_run(run_dir, spec), episodes, tolerances, seed, oracle, workers, write, progress, started,
                         lookahead, refining)
    finally:
        if owned:
            run_dir.release()


def _evaluate(loaded: LoadedRun, episodes: int, tolerances: Optional[Sequence[int]], seed: int, oracle: str,
              workers: Optional[int], write: Optional[bool], progress=None, started=None,
              lookahead: int = 0, refining=None) -> Evaluation:
    prog, cfg = loaded.program, loaded.config
    task = prog.task(cfg.task).model
    tols = list(tolerances) if tolerances else list(task.tolerances)
    for T in tols:
        if not 1 <= int(T) <= task.deadline:
            raise ValueError(f"tolerance {T} is outside 1..{task.deadline} (the task's deadline: episodes end there)")
    check_batch(prog, cfg.task, int(episodes), f"--episodes {int(episodes):,}", cfg.reward)  # exit 2 beyond memory
    controller = loaded.controller()
    method = f"{cfg.algo} ({cfg.reward} reward, {cfg.preset} preset, seed {cfg.seed})"
    if lookahead:
        from ..compare.controllers import LookaheadController

        controller = LookaheadController(prog, controller, cfg.task, hold=int(lookahead),  # ValueError: why not
                                         progress=refining)
        method += f", refined by a look-ahead holding actions up to {int(lookahead)} steps"
        write = False  # eval.json is the policy's own evaluation
    start = time.perf_counter()
    states = task_states(prog.system, task, int(episodes), seed=seed)
    result = Evaluator(prog, cfg.task, states, reward=cfg.reward).run(controller)
    seconds = time.perf_counter() - start
    ceiling = None
    if oracle != "off":
        from ..oracle.cache import oracle_for

        ceiling = oracle_for(prog, cfg.task, seed, int(episodes), compute=oracle == "auto", workers=workers,
                             partial=True, progress=progress, started=started)
    ev = summarise(result, method=method,
                   prog=prog, task=cfg.task, seed=seed, tolerances=tols, oracle=ceiling, seconds=seconds)
    if lookahead:
        holds = ", ".join(str(h) for h in controller.holds)
        ev.notes.append(f"each action chosen on the spec's simulator among {controller.K} candidates (the policy's "
                        f"own, grid actions held {holds} steps, the rest of the last choice), the policy after "
                        f"them; the policy's own kept unless one reaches sooner (one did at {controller.refined:,} "
                        "steps of the states)")
    if ceiling is not None and ceiling.unstored:
        ev.notes.append(f"the oracle's results are not cached ({ceiling.unstored}): the next evaluation "
                        "computes them again")
    if seed == cfg.validation_seed:
        ev.notes.append(f"seed {seed} draws the validation states this run selected its model on: "
                        "these rates flatter it")
    if write is None:  # the run's own evaluation: its episode count, seed 2024, the task's tolerances
        write = seed == EVAL_SEED and int(episodes) == cfg.eval_episodes and not tolerances
    if write:
        try:
            loaded.run.write_eval(ev.to_dict(), loaded.model_file)
        except RunWriteError as err:
            err.evaluation = ev  # computed all the same: the caller may still show it
            raise
    return ev
