"""Training runs: ``asap_dsl.train`` and ``asapc train``.

A run trains one task of a spec with an engine of :mod:`.engines` (stable-baselines3, or sbx: its
API on JAX), validates the policy periodically on initial states of its own seed
(:data:`~asap_dsl.backends.rl.config.VALIDATION_SEED`, never the evaluation seed) and keeps the
best model, writes curves (CSV and TensorBoard), checkpoints the model, replay buffer and random
state periodically and on Ctrl-C / SIGTERM, and finally evaluates the best model on the seeded
evaluation states. ``resume=True`` continues a checkpoint with the same step count, replay buffer
and random state. The directory layout is :mod:`asap_dsl.runs`.
"""

from __future__ import annotations

import json
import pickle
import random
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Protocol, Sequence, Union

import numpy as np

from asap_dsl.program import Program, load
from asap_dsl.rollout import Evaluator
from asap_dsl.processes import Interrupts
from asap_dsl.runs import (Checkpoint, RunDir, RunError, check_target, checkpoint_seconds, create_run, default_run_name,
                           json_safe, package_versions, spec_hash, stamp)
from asap_dsl.sampling import task_states

from .config import ConfigError, TrainConfig, resolve_config
from .curriculum import failed_starts_env
from .demonstrations import keep
from .presets import OFF_POLICY, get_preset
from .engines import Engine, get_engine
from .exploration import LateDemonstrations, add_late
from . import hyper as _hyper
from .sb3 import PolicyController, Scaling, ScaledVecEnv
from .validation import Schedule, log_validation, plateau_reached, rule_text, validation_score, write_curves

__all__ = ["TrainProgress", "TrainResult", "train", "validation_score"]

CHECKPOINT_SECONDS = checkpoint_seconds()  # wall time between periodic checkpoints (ASAP_CHECKPOINT_SECONDS)


class TrainProgress(Protocol):
    """What a live display is told (the CLI draws it with rich; a sweep aggregates it)."""

    def start(self, config: TrainConfig, done: int, ceiling: Optional[dict]) -> None: ...

    def advance(self, done: int) -> None: ...

    def validated(self, row: dict) -> None: ...

    def finish(self) -> None: ...

    # Optional: ``note(line)``, a line for the log before training starts (the demonstrations).


@dataclass
class TrainResult:
    """What a run produced. ``evaluation`` is the final evaluation (None when interrupted)."""

    run_dir: Path
    config: TrainConfig
    steps: int
    seconds: float
    status: str  # finished | interrupted
    best: Optional[dict]
    evaluation: Any = None
    curves: list = field(default_factory=list)

    @property
    def interrupted(self) -> bool:
        return self.status == "interrupted"

    @property
    def never_succeeded(self) -> bool:
        """Every validation scored 0 at every tolerance (the model kept is then the latest)."""
        return bool(self.curves) and all(r["score"] == 0 for r in self.curves)

    @property
    def resume_command(self) -> str:
        """The command that continues this run, shell-quoted, ready to paste."""
        run = RunDir(self.run_dir)
        return run.command(run.read_manifest(), "--resume")


# ------------------------------------------------------------------------------------ checkpoints
def _rng_state(venv, model, engine: Engine) -> dict:
    # "actions": the random actions before learning starts (the model re-seeds them on loading).
    return {"python": random.getstate(), "numpy": np.random.get_state(), "env": venv.core.rng.bit_generator.state,
            "actions": model.action_space.np_random.bit_generator.state, **engine.rng_state(model)}


def _set_rng_state(state: dict, venv, model, engine: Engine) -> None:
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    venv.core.rng.bit_generator.state = state["env"]
    if "actions" in state:  # checkpoints written before it was kept lack it
        model.action_space.np_random.bit_generator.state = state["actions"]
    engine.set_rng_state(model, state)


def _save_checkpoint(run: RunDir, model, venv, algo: str, extra: dict, engine: Engine, **changes: Any) -> None:
    """Write the checkpoint through the run directory: the files in full, then their records in
    the manifest (with ``changes``), then swapped in; the previous one stays valid until then."""
    def state_pickle(path: Path) -> None:
        with open(path, "wb") as f:
            pickle.dump({"rng": _rng_state(venv, model, engine), **extra}, f)

    def state_json(path: Path) -> None:
        summary = {k: v for k, v in extra.items() if k != "curves"}
        path.write_text(json.dumps(json_safe(summary), indent=2, allow_nan=False) + "\n", encoding="utf-8")

    files = {"model.zip": lambda path: model.save(str(path))}
    if algo in OFF_POLICY:
        files["replay.pkl"] = lambda path: model.save_replay_buffer(str(path))
    files["state.pkl"], files["state.json"] = state_pickle, state_json
    run.save_checkpoint(files, int(extra["steps"]), **changes)


# ------------------------------------------------------------------------------------ the run
def _callbacks():
    from stable_baselines3.common.callbacks import BaseCallback

    class RunCallback(BaseCallback):
        """Validation, checkpoints, progress and stopping, in one pass per environment step."""

        def __init__(self, session: "_Session"):
            super().__init__()
            self.s = session

        def _on_step(self) -> bool:
            s = self.s
            n = self.num_timesteps
            if s.progress is not None:
                s.progress.advance(n)
            if s.kept_rows:  # before the step's transitions are stored (SB3 stores after on_step)
                keep(self.model.replay_buffer, s.kept_rows)
            if s.schedule.due(n, s.seconds):
                s.validate(self.model, n, self.logger)
                if s.plateaued(n):
                    s.plateau_step = n
                    return False
            if s.stop.signal is not None:
                return False
            if s.cfg.time_limit is not None and s.seconds >= s.cfg.time_limit:
                s.time_up = True
                return False
            if time.perf_counter() - s.last_checkpoint >= CHECKPOINT_SECONDS:  # noqa: SIM102
                s.checkpoint(self.model)
            return True

    return RunCallback


class _Session:
    """One process's share of a run: from a fresh start or a checkpoint to the end or a stop."""

    def __init__(self, prog: Program, cfg: TrainConfig, run: RunDir, progress: Optional[TrainProgress],
                 callbacks: Sequence = (), stop: Optional[Interrupts] = None):
        import torch

        from asap_dsl.env import make_vec_env

        self.prog, self.cfg, self.run, self.progress = prog, cfg, run, progress
        self.engine = get_engine(cfg.engine)
        self.extra_callbacks = list(callbacks)
        if cfg.torch_threads > 0:
            torch.set_num_threads(cfg.torch_threads)
        self.task = prog.task(cfg.task).model
        self.tolerances = sorted(self.task.tolerances)
        self.scaling = Scaling.for_run(prog.system, cfg, self.task.init_box)
        self.raw_env = make_vec_env(prog, cfg.task, num_envs=cfg.n_envs, seed=cfg.seed, reward=cfg.reward,
                                    failure_reward=cfg.failure_reward)
        # The failed-starts curriculum (:mod:`.curriculum`) is the learner's alone: not the replays'.
        self.curriculum = (failed_starts_env(self.raw_env, cfg.failed_starts, cfg.seed)
                           if cfg.failed_starts > 0 else None)
        self.env = self.learner_env(self.raw_env if self.curriculum is None else self.curriculum)
        self.failure_reward = cfg.failure_reward  # the learner's reward of a failure step, as the discount has it
        val_states = task_states(prog.system, self.task, cfg.validation_episodes, seed=cfg.validation_seed)
        self.validator = Evaluator(prog, cfg.task, val_states, reward=cfg.reward)
        self.curves: list[dict] = []
        self.best: Optional[dict] = None
        self.validations = max(1, cfg.steps // max(1, cfg.validate_every))
        # A time-limited run validates on the clock too (:mod:`.validation`).
        self.schedule = Schedule(cfg.validate_every, None if cfg.time_limit is None else cfg.time_limit / self.validations)
        self.seconds_before = 0.0
        # The default preset's demonstrations when the run needs them (:mod:`.exploration`), None
        # where there are none.
        self.late = (LateDemonstrations(cfg.late_demonstrations, get_preset(cfg.preset).late_after,
                                        cfg.stall_demonstrations, cfg.plateau or get_preset(cfg.preset).plateau,
                                        cfg.sparse_gamma)
                     if cfg.late_demonstrations > 0 or cfg.stall_demonstrations > 0 else None)
        self.stop = stop if stop is not None else Interrupts()
        self.kept_rows = 0  # the demonstrations' rows of the replay buffer, never overwritten
        self.time_up = False
        self.plateau_step: Optional[int] = None  # where validation stopped improving, and the run ended
        self.last_checkpoint = time.perf_counter()
        self.started = time.perf_counter()

    @property
    def seconds(self) -> float:
        return self.seconds_before + (time.perf_counter() - self.started)

    def learner_env(self, raw):
        """A raw vector env of the task as the learner sees it (scaled, the deadline's handling),
        its episodes counted for stable-baselines3's ``rollout/ep_rew_mean`` and ``ep_len_mean``."""
        from stable_baselines3.common.vec_env import VecMonitor

        return VecMonitor(_LearnerEnv(ScaledVecEnv(raw, self.scaling), self.cfg.time_limit_terminal))

    def witnesses(self) -> Optional[Any]:
        """A new run's demonstration sequences from the oracle (:mod:`.demonstrations`), before
        the model is built (its workers are forked: not from a process running JAX). Their wall
        time counts as the run's, the time limit's included. None where the run has none."""
        from .demonstrations import longest, search_count, searcher, solve, unavailable

        if self.cfg.demonstrations <= 0:
            why = unavailable(self.prog, self.cfg.algo)
            if why and get_preset(self.cfg.preset).demonstrations > 0:  # the preset's, withheld: say why
                self._tell(f"demonstrations: none ({why})")
            return None

        def check_stop() -> None:
            if self.stop.requested:
                raise KeyboardInterrupt

        budget = self.cfg.demonstration_seconds
        count = search_count(self.prog, self.cfg.demonstrations, budget_seconds=budget)
        self._tell(f"demonstrations: the {searcher(self.prog)} on {count:,} initial states of the run's own seed"
                   + ("" if budget is None else f", for at most {budget:.0f} s") + " ...")
        found = solve(self.prog, self.cfg.task, self.cfg.demonstrations, self.cfg.seed, budget_seconds=budget,
                      check_stop=check_stop)
        return longest(found, self.cfg.demonstration_share, self.cfg.demonstration_repeat)

    def demonstrate(self, model, witnesses) -> dict:
        """The witnesses' transitions into ``model``'s replay buffer, told to the progress display."""
        from .demonstrations import add_demonstrations

        demos = add_demonstrations(self.prog, self.cfg.task, model, self.learner_env, self.scaling, witnesses,
                                   reward=self.cfg.reward, failure_reward=self.cfg.failure_reward)
        self.seconds_before += demos.seconds
        self.kept_rows = demos.rows
        self.started = time.perf_counter()  # what came before is counted in the line above
        if self.cfg.time_limit is not None:  # validations on the clock: spread over the time left
            self.schedule.restart_clock(self.seconds_before, max(0.0, self.cfg.time_limit - self.seconds_before),
                                        self.validations)
        self._tell(demos.text())
        return demos.to_dict()

    def plateaued(self, steps: int) -> bool:
        """Whether the run ends on the plateau rule (:func:`.validation.plateau_reached`), once
        ``plateau_after`` of its steps are done. A run waits for the late demonstrations while they
        may still come (it has found nothing, or a stall would bring them), and once they have come
        it is judged on the validations after the latest alone."""
        if self.cfg.plateau is None or steps < (self.cfg.plateau_after or 0.0) * self.cfg.steps:
            return False
        curves = self.curves
        if self.late is not None:
            if self.late.may_fire(curves):
                return False
            curves = self.late.recent(curves)
        return plateau_reached(curves, steps, self.cfg.plateau)

    def set_discount(self, model, gamma: float) -> None:
        """The learner's discount becomes ``gamma`` mid-run (the late rule, :mod:`.exploration`).
        A failure step earns the reward's floor for every step after it, ``floor / (1 - gamma)``:
        its reward follows the discount, in the learner's steps and in those already stored (the
        env's failure reward is compiled in; the stored ones are exactly that constant)."""
        model.gamma = float(gamma)
        if self.cfg.failure_reward is None:
            return
        was = self.failure_reward
        start = float(self.cfg.hyper.get("gamma", 0.99))  # the discount cfg.failure_reward was made for
        self.failure_reward = float(self.cfg.failure_reward) * (1.0 - start) / (1.0 - float(gamma))
        self.env.venv.failure_reward = self.failure_reward
        buffer = getattr(model, "replay_buffer", None)
        if buffer is not None and was != self.failure_reward:
            buffer.rewards[buffer.rewards == np.float32(was)] = np.float32(self.failure_reward)

    def _tell(self, line: str) -> None:
        note = getattr(self.progress, "note", None)  # optional in TrainProgress
        if note is not None:
            note(line)

    def ceiling(self) -> Optional[dict]:
        """The oracle's ceiling per tolerance on the evaluation states, when it is cached, for them
        or the first of them (shown beside the validation rates; the oracle is never computed
        during training)."""
        from asap_dsl.sampling import EVAL_SEED

        from ..oracle.cache import oracle_for

        hit = oracle_for(self.prog, self.cfg.task, EVAL_SEED, self.cfg.eval_episodes, compute=False, partial=True)
        return None if hit is None else {T: hit.ceiling(T)["rate"] for T in self.tolerances}

    # -- validation
    def validate(self, model, steps: int, logger=None) -> dict:
        t0 = time.perf_counter()
        res = self.validator.run(PolicyController(model, self.scaling))
        rates = {T: res.rate(T) for T in self.tolerances}
        score = validation_score(rates)
        better = self.best is None or score >= self.best["score"]  # a tie: the later model, trained longer
        row = {"steps": int(steps), "seconds": round(self.seconds, 3), "score": round(score, 6), "rates": rates,
               "best": int(better), "return": round(float(np.mean(res.returns)), 6)}
        self.curves.append(row)
        if better:
            self.best = dict(row)
            self.run.save_model(lambda path: model.save(str(path)), best=self.best)
        write_curves(self.run, self.curves, self.tolerances)
        if logger is not None:
            log_validation(model, logger, int(steps), rates, score)
        self.schedule.done(int(steps), self.seconds, time.perf_counter() - t0)
        if self.progress is not None:
            self.progress.validated(row)
        why = (None if self.late is None or self.time_up or steps >= self.cfg.steps  # not after the last
               else self.late.due(self.curves, int(steps), self.cfg.steps, self.seconds, self.cfg.time_limit))
        if why is not None:
            add_late(self, model, int(steps), why)
        return row

    # -- checkpoints
    def state(self, model) -> dict:
        return {"steps": int(model.num_timesteps), "seconds": self.seconds, "best": self.best,
                "curves": self.curves, "late_demonstrations": None if self.late is None else self.late.added,
                "failed_starts": None if self.curriculum is None else self.curriculum.state(),
                "demonstration_rows": self.kept_rows,
                **self.schedule.to_dict()}

    def checkpoint(self, model, run: Optional[RunDir] = None) -> None:
        """A checkpoint of ``model`` into the run (or ``run``: a new run's first, before it is in place)."""
        _save_checkpoint(run or self.run, model, self.raw_env, self.cfg.algo, self.state(model), self.engine,
                         steps_done=int(model.num_timesteps), seconds=round(self.seconds, 3))
        self.last_checkpoint = time.perf_counter()

    def restore(self, ckpt: Checkpoint):
        """The model and the session's state from a checkpoint whose files the manifest vouches for."""
        try:
            with open(ckpt.path("state.pkl"), "rb") as f:
                state = pickle.load(f)
            model = self.engine.load(self.cfg.algo, ckpt.path("model.zip"), env=self.env)
            if self.cfg.algo in OFF_POLICY:
                model.load_replay_buffer(str(ckpt.path("replay.pkl")))
        except RunError:
            raise
        except Exception as err:  # noqa: BLE001 — matches its record, yet unloadable: a foreign or old file
            raise RunError(f"{ckpt.directory}: the checkpoint cannot be loaded ({type(err).__name__}); train the run "
                           f"again with `{self.run.command(self.run.read_manifest(), '--force')}`") from None
        _set_rng_state(state["rng"], self.raw_env, model, self.engine)
        self.best, self.curves = state["best"], list(state["curves"])
        self.schedule.restore(state)
        if self.late is not None:  # added before the checkpoint: never again
            self.late.restore(state.get("late_demonstrations"))
            if self.late.gamma is not None:  # the model keeps its discount; the failure step's reward follows it
                self.set_discount(model, self.late.gamma)
        self.kept_rows = int(state.get("demonstration_rows") or 0)
        if self.curriculum is not None and state.get("failed_starts") is not None:
            self.curriculum.restore(state["failed_starts"])
        self.seconds_before = float(state["seconds"])
        if int(model.num_timesteps) != int(state["steps"]):
            raise RunError(f"{self.run.path}: the checkpoint is inconsistent (model at step {model.num_timesteps}, "
                           f"state at step {state['steps']}); train the run again with "
                           f"`{self.run.command(self.run.read_manifest(), '--force')}`")
        return model

    # -- the loop
    def learn(self, model) -> str:
        remaining = self.cfg.steps - int(model.num_timesteps)
        if self.progress is not None:
            self._tell(rule_text(self.cfg.validation_episodes, self.validations))
            self.progress.start(self.cfg, int(model.num_timesteps), self.ceiling())
        self.started = time.perf_counter()
        self.last_checkpoint = self.started
        try:
            if remaining > 0 and self.stop.signal is None:
                model.learn(total_timesteps=remaining, callback=[_callbacks()(self), *self.extra_callbacks],
                            reset_num_timesteps=model.num_timesteps == 0, tb_log_name="train", progress_bar=False)
            stopped = self.stop.signal is not None
            if not stopped and (not self.curves or self.curves[-1]["steps"] != model.num_timesteps):
                self.validate(model, int(model.num_timesteps), getattr(model, "_logger", None))
            self.checkpoint(model)
        finally:
            if self.progress is not None:
                self.progress.finish()
        if self.plateau_step is not None:
            self._tell(f"validation stopped improving: the run ends at step {self.plateau_step:,} of "
                       f"{self.cfg.steps:,} (no gain over the latest {self.cfg.plateau:.0%} of its steps)")
        if self.curves:
            spent = self.schedule.spent
            self._tell(f"validation: {len(self.curves)} times, {spent:.1f} s of the run's {self.seconds:.1f} s "
                       f"({spent / max(self.seconds, 1e-9):.0%})")
        return "interrupted" if stopped else "finished"


def _wrapper_base():
    from stable_baselines3.common.vec_env import VecEnvWrapper

    return VecEnvWrapper


class _LearnerEnv(_wrapper_base()):
    """With the time left in the observation, the deadline ends a finite-horizon problem: the
    time-out is terminal (no bootstrapping past it). ``failure_reward`` (None: the env's) is a
    failure step's reward once the discount changed mid-run (:meth:`_Session.set_discount`)."""

    def __init__(self, venv, terminal: bool):
        super().__init__(venv)
        self.terminal = terminal
        self.failure_reward: Optional[float] = None

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        obs, reward, done, infos = self.venv.step_wait()
        if done.any() and (self.terminal or self.failure_reward is not None):
            for i in np.flatnonzero(done):
                if self.failure_reward is not None and not infos[i].get("TimeLimit.truncated", False):
                    reward[i] = self.failure_reward  # terminated before the deadline: a failure
                if self.terminal:
                    infos[i]["TimeLimit.truncated"] = False
        return obs, reward, done, infos


# ------------------------------------------------------------------------------------ entry point
def _program(spec: Union[str, Path, Program]) -> Program:
    return spec if isinstance(spec, Program) else load(spec)


def _explicit_conflicts(stored: TrainConfig, fresh: TrainConfig, given: Mapping[str, Any]) -> list[str]:
    out = []
    for name, value in given.items():
        if value is None or name == "steps":
            continue
        if name == "settings":
            for k, v in value.items():
                if stored.hyper.get(k) != v:
                    out.append(f"{k} = {v} (the run has {stored.hyper.get(k)})")
            continue
        if getattr(fresh, name) != getattr(stored, name):
            out.append(f"--{name.replace('_', '-')} {getattr(fresh, name)} (the run has {getattr(stored, name)})")
    return out


def train(spec: Union[str, Path, Program], task: Optional[str] = None, *, algo: Optional[str] = None,
          reward: Optional[str] = None, steps: Optional[int] = None, seed: Optional[int] = None,
          preset: Optional[str] = None, n_envs: Optional[int] = None, out: Union[str, Path, None] = None,
          runs_dir: Union[str, Path] = "runs", resume: bool = False, force: bool = False,
          settings: Optional[Mapping[str, Any]] = None, progress: Optional[TrainProgress] = None,
          evaluate: bool = True, eval_episodes: Optional[int] = None, callbacks: Sequence = (),
          time_limit: Optional[float] = None, engine: Optional[str] = None,
          demonstrations: Optional[int] = None, failed_starts: Optional[float] = None) -> TrainResult:
    """Train ``task`` of a spec with stable-baselines3's API (on torch or JAX) and evaluate the
    best model.

    Precedence of settings: these arguments, then the task's ``train { ... }`` block, then the
    preset. Ctrl-C or SIGTERM stop the run after a checkpoint: the result's status is then
    ``interrupted``, and ``resume=True`` continues it later.

    :param spec: the spec: a path, or a program already loaded (:func:`asap_dsl.load`).
    :param task: the task to train (default: the spec's only task).
    :param algo: the algorithm, one of :data:`asap_dsl.checker_common.ALGORITHMS` (default: the
        task's ``train`` block, else the preset's, ``sac``).
    :param reward: the reward, a kind or a kind with settings as the language writes it
        (``asap``, ``rho(window = 5)``, ``distance``, ...; default: the task's own). A bare kind
        that is the task's own keeps the task's settings.
    :param steps: environment steps in total (default: the ``train`` block's, else the
        preset's; with ``resume``: the new total).
    :param seed: the run's seed (default: the ``train`` block's, else 0).
    :param preset: ``default`` or ``paper`` (:mod:`asap_dsl.backends.rl.presets`).
    :param n_envs: environments stepped together (default: the ``train`` block's, else the preset's).
    :param engine: what trains, ``sbx`` (JAX) or ``sb3`` (stable-baselines3 on torch;
        :mod:`asap_dsl.backends.rl.engines`); default: the preset's where it has the algorithm.
    :param out: the run directory (default ``<runs_dir>/<spec>-<task>-<algo>-<reward>-s<seed>``).
    :param runs_dir: where the default run directory goes.
    :param resume: continue the run in ``out`` from its checkpoint (same step count, replay
        buffer and random state); the settings given must agree with the run's.
    :param force: replace an existing run (never replaced otherwise).
    :param settings: hyperparameters by their ``train { ... }`` names (over the block and the preset).
    :param progress: told of the run's start, steps and validations (:class:`TrainProgress`).
    :param evaluate: evaluate the best model on the seeded evaluation states once finished.
    :param eval_episodes: evaluation states (default: the ``train`` block's, else 1000).
    :param callbacks: extra stable-baselines3 callbacks (one returning False ends the run early,
        as finished).
    :param time_limit: seconds of training after which the run ends, as finished (the
        demonstrations' time included).
    :param demonstrations: initial states whose oracle action sequences go into the replay buffer
        before learning (:mod:`asap_dsl.backends.rl.demonstrations`; default: the preset's where
        the algorithm is off-policy and the dynamics known; 0: none). A resumed run keeps its own.
    :param failed_starts: the share of new training episodes that start at the initial state of an
        earlier one that did not reach (:mod:`asap_dsl.backends.rl.curriculum`; default: the preset's).
    :return: the run's directory, configuration, steps, best validation and final evaluation.
    :raises asap_dsl.SpecError: the spec does not load.
    :raises ConfigError: a setting cannot be used (one sentence).
    :raises asap_dsl.runs.RunError: the run directory (exists, changed spec, no checkpoint, ...).
    :raises KeyError: an unknown task.
    """
    stop = Interrupts()
    with stop:  # before anything is created: from here on, Ctrl-C and SIGTERM end in a checkpoint
        prog = _program(spec)
        cfg = resolve_config(prog, task, algo=algo, reward=reward, steps=steps, seed=seed, preset=preset,
                             n_envs=n_envs, settings=settings, eval_episodes=eval_episodes, time_limit=time_limit,
                             engine=engine, demonstrations=demonstrations, failed_starts=failed_starts)
        _check_memory(prog, cfg)
        run = RunDir(out if out is not None else Path(runs_dir) / default_run_name(prog.file, cfg.task, cfg.algo,
                                                                                 cfg.reward, cfg.seed))
        given = {"task": task, "algo": algo, "engine": engine, "reward": reward, "seed": seed, "preset": preset,
                 "n_envs": n_envs, "demonstrations": demonstrations,
                 "failed_starts": failed_starts,
                 "settings": _hyper.normalise(dict(settings or {}), "settings")}  # as the run stores them
        try:
            return _run(prog, cfg, run, stop, resume=resume, force=force, given=given, steps=steps,
                        time_limit=time_limit, progress=progress, callbacks=callbacks, evaluate=evaluate)
        finally:
            run.release()


def _check_memory(prog: Program, cfg: TrainConfig) -> None:
    """Refuse (exit 2) environments or validation states beyond what the machine's memory holds:
    the batched environments, and beside each the policy's activations and its rollout (float32)."""
    from asap_dsl.limits import ResourceLimit, check_batch

    arch = cfg.hyper.get("net_arch")
    width = sum(arch) if isinstance(arch, (list, tuple)) and all(isinstance(w, int) for w in arch) else 1024
    obs, act = prog.system.n_state + 1, prog.system.n_action
    rollout = int(cfg.hyper.get("n_steps", 1)) if cfg.algo not in OFF_POLICY else 1
    per_env = 4 * (3 * width + 4 * (obs + act)) + 4 * rollout * (2 * obs + act + 4)
    try:
        check_batch(prog, cfg.task, cfg.n_envs, f"--envs {cfg.n_envs:,}", cfg.reward, per_env)
        check_batch(prog, cfg.task, cfg.validation_episodes, f"{cfg.validation_episodes:,} validation states",
                    cfg.reward, 4 * 3 * width)
        if cfg.demonstrations:  # replayed side by side, each with an episode of transitions kept
            check_batch(prog, cfg.task, cfg.demonstrations, f"{cfg.demonstrations:,} demonstrations", cfg.reward,
                        4 * (prog.task(cfg.task).model.episode[1] + 1) * (2 * obs + act + 3))
    except ResourceLimit as err:
        raise ConfigError(str(err)) from None


def _open_for_resume(prog: Program, cfg: TrainConfig, run: RunDir, given: Mapping[str, Any],
                     steps: Optional[int], time_limit: Optional[float]) -> tuple[TrainConfig, Checkpoint]:
    """Lock the run, check that it is the one asked for, and find its checkpoint."""
    run.acquire(exclusive=True)
    manifest = run.read_manifest()
    if manifest["spec_hash"] != spec_hash(prog.source):
        raise RunError(f"{run.path}: {prog.file} has changed since this run was trained; train a new run "
                       "(another --out), or replace this one with --force")
    try:
        stored = TrainConfig.from_dict(manifest["config"])
    except (ConfigError, TypeError) as err:
        raise RunError(f"{run.manifest_path}: damaged manifest (its configuration: {err}); replace the run "
                       f"with `{run.command(manifest, '--force')}`") from None
    conflicts = _explicit_conflicts(stored, cfg, given)
    if conflicts:
        raise RunError(f"{run.path}: --resume continues the run as it was configured; it differs in "
                       + "; ".join(conflicts))
    if steps is not None:
        stored.steps = int(steps)
    if time_limit is not None:
        stored.time_limit = float(time_limit)
    ckpt = run.checkpoint(manifest)
    if ckpt is None:
        raise RunError(f"{run.path}: no checkpoint to resume from; train the run again with "
                       f"`{run.command(manifest, '--force')}`")
    return stored, ckpt


def _run(prog: Program, cfg: TrainConfig, run: RunDir, stop: Interrupts, *, resume: bool, force: bool,
         given: Mapping[str, Any], steps: Optional[int], time_limit: Optional[float],
         progress: Optional[TrainProgress], callbacks: Sequence, evaluate: bool) -> TrainResult:
    if resume:
        cfg, ckpt = _open_for_resume(prog, cfg, run, given, steps, time_limit)
        run.interrupts = stop
        session = _Session(prog, cfg, run, progress, callbacks, stop)
        with run.guard():
            model = session.restore(ckpt)
            m = run.read_manifest()
            if m["status"] == "finished" and (cfg.steps <= int(model.num_timesteps) or "plateau_step" in m):
                return _finished(run, cfg, session, evaluate)
            run.update_manifest(status="running", config=cfg.to_dict(), error=None)
    else:
        if check_target(run.path, force) or run.path.is_dir():  # refused before anything is built
            run.acquire(exclusive=True)  # the run it replaces (or the empty directory) is ours until then
        session = _Session(prog, cfg, run, progress, callbacks, stop)
        witnesses = session.witnesses()
        try:
            model = session.engine.build(cfg.algo, session.env, cfg.hyper, cfg.seed,
                                         tensorboard_log=str(run.tensorboard_dir))
        except (TypeError, ValueError, AssertionError) as err:  # a value the library itself refused
            raise ConfigError(f"the {cfg.engine} engine's {cfg.algo.upper()} refused the settings: "
                              f"{str(err).rstrip('.') or type(err).__name__}") from None
        # Before the run exists: its first checkpoint holds them, so a resume never adds them again.
        demos = session.demonstrate(model, witnesses) if witnesses is not None else None
        if stop.requested:  # nothing was created yet
            raise KeyboardInterrupt
        spec_file = str(Path(prog.file).resolve())
        manifest = {"spec_file": spec_file, "spec_hash": spec_hash(prog.source), "task": cfg.task,
                    "config": cfg.to_dict(), "versions": package_versions(), "status": "running", "steps_done": 0,
                    "seconds": 0.0, "created": stamp()}
        if demos is not None:
            manifest["demonstrations"] = json_safe(demos)
        # Created whole, with a checkpoint at step 0: a run directory that exists can be resumed.
        created = create_run(run.path, manifest, prog.source, force=force, interrupts=stop, held=run.lock,
                             initial=lambda staged: session.checkpoint(model, staged))
        run.lock, run.interrupts = created.lock, stop  # the caller releases it
    try:
        with run.guard():
            status = session.learn(model)
            # A run that ended on the plateau is complete at fewer steps: resume and tune read this.
            ended = {} if session.plateau_step is None else {"plateau_step": int(session.plateau_step)}
            run.update_manifest(status=status, steps_done=int(model.num_timesteps),
                                seconds=round(session.seconds, 3), best=session.best, **ended)
    except KeyboardInterrupt:  # aborted by a third signal: the last checkpoint stands
        try:
            run.update_manifest(status="interrupted")
        except RunError:
            pass
        raise
    stop.__exit__()  # the evaluation that follows is not a run's write: Ctrl-C ends it at once
    result = TrainResult(run.path, cfg, int(model.num_timesteps), session.seconds, status, session.best,
                         curves=session.curves)
    if status == "finished" and evaluate:
        from .evaluation import evaluate as run_evaluation

        with run.guard(status="finished"):
            result.evaluation = run_evaluation(run, episodes=cfg.eval_episodes, oracle="cache")
    return result


def _finished(run: RunDir, cfg: TrainConfig, session: _Session, evaluate: bool) -> TrainResult:
    """A resumed run that has nothing left to train: report it as it stands."""
    manifest = run.read_manifest()
    result = TrainResult(run.path, cfg, int(manifest.get("steps_done", 0)), float(manifest.get("seconds", 0.0)),
                         "finished", manifest.get("best"), curves=session.curves)
    if evaluate:
        from .evaluation import evaluate as run_evaluation

        with run.guard(status="finished"):
            result.evaluation = run_evaluation(run, episodes=cfg.eval_episodes, oracle="cache")
    return result


__all__ += ["ConfigError"]
