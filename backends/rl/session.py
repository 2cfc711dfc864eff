"""One process's share of a training run (:mod:`.training`): the learner's environments, the
periodic validation and the model it keeps, the default preset's late demonstrations
(:mod:`.exploration`), checkpoints and their restoring, and the callback that drives them from the
learning loop. :func:`~.training.train` opens the run directory and builds a :class:`Session`;
the session never parses a spec or resolves a configuration.
"""

from __future__ import annotations

import json
import pickle
import random
import time
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional, Sequence

import numpy as np

from asap_dsl.program import Program
from asap_dsl.rollout import Evaluator
from asap_dsl.processes import Interrupts
from asap_dsl.runs import Checkpoint, RunDir, RunError, checkpoint_seconds, json_safe
from asap_dsl.sampling import task_states

from .config import TrainConfig
from .curriculum import failed_starts_env
from .demonstrations import keep
from .imitation import IMITATION_STATE_SECONDS, set_imitation
from .policy_search import SEARCHABLE, ActorFamily, PolicySearch, SearchSettings, SearchState
from .presets import OFF_POLICY, get_preset
from .engines import Engine, get_engine
from .exploration import LateDemonstrations, add_late
from .sb3 import PolicyController, Scaling, ScaledVecEnv
from .validation import Schedule, log_validation, plateau_reached, rule_text, validation_score, write_curves

if TYPE_CHECKING:
    from .training import TrainProgress

__all__ = ["CHECKPOINT_SECONDS", "LearnerEnv", "Session"]

CHECKPOINT_SECONDS = checkpoint_seconds()  # wall time between periodic checkpoints (ASAP_CHECKPOINT_SECONDS)


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
        summary = {k: v for k, v in extra.items() if k not in ("curves", "policy_search")}
        if extra.get("policy_search") is not None:  # its parameters are the pickle's
            summary["policy_search"] = {k: extra["policy_search"][k] for k in ("iteration", "best_score",
                                                                               "best_iteration")}
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

        def __init__(self, session: "Session"):
            super().__init__()
            self.s = session

        def _on_step(self) -> bool:
            s = self.s
            n = self.num_timesteps
            if s.progress is not None:
                s.progress.advance(n)
            kept = s.kept
            if kept:  # before the step's transitions are stored (SB3 stores after on_step)
                keep(self.model.replay_buffer, kept)
            if s.schedule.due(n, s.seconds):
                s.validate(self.model, n, self.logger)
                if s.plateaued(n):
                    s.plateau_step = n
                    return False
            if s.stop.signal is not None:
                return False
            if s.learning_seconds is not None and s.seconds >= s.learning_seconds:
                s.time_up = True
                return False
            if time.perf_counter() - s.last_checkpoint >= CHECKPOINT_SECONDS:  # noqa: SIM102
                s.checkpoint(self.model)
            return True

    return RunCallback


class Session:
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
        self.schedule = Schedule(cfg.validate_every, None if cfg.time_limit is None else cfg.time_limit / self.validations,
                                 cost=cfg.validation_episodes * int(self.task.episode[1]))
        self.seconds_before = 0.0
        # The default preset's demonstrations when the run needs them (:mod:`.exploration`), None
        # where there are none.
        self.late = (LateDemonstrations(cfg.late_demonstrations, get_preset(cfg.preset).late_after,
                                        cfg.stall_demonstrations, cfg.plateau or get_preset(cfg.preset).plateau,
                                        cfg.sparse_gamma, cfg.sparse_imitation, cfg.imitation_states)
                     if cfg.late_demonstrations > 0 or cfg.stall_demonstrations > 0 else None)
        self.stop = stop if stop is not None else Interrupts()
        self.kept_rows = 0  # the demonstrations' rows of the replay buffer, never overwritten
        self.time_up = False
        self.plateau_step: Optional[int] = None  # where validation stopped improving, and the run ended
        self.learned = False  # the learner is done for good (its steps, its plateau, its share of the time)
        self.search: Optional[SearchState] = None  # the policy search's (:mod:`.policy_search`), once begun
        self.last_checkpoint = time.perf_counter()
        self.started = time.perf_counter()

    @property
    def seconds(self) -> float:
        return self.seconds_before + (time.perf_counter() - self.started)

    @property
    def learning_seconds(self) -> Optional[float]:
        """When the learner stops on the clock: the time limit, less the policy search's share."""
        if self.cfg.time_limit is None:
            return None
        share = 0.0 if self.cfg.policy_search is None else float(self.cfg.policy_search["time_share"])
        return self.cfg.time_limit * (1.0 - share)

    @property
    def kept(self) -> list[tuple[int, int]]:
        """``(start, rows)`` of the replay buffer never overwritten: the demonstrations stored at
        its start, and the paths the late rule stored mid-run for the actor to imitate."""
        out = [(0, self.kept_rows)] if self.kept_rows else []
        late = None if self.late is None else self.late.imitated
        if late is not None and late.get("rows"):
            out.append((int(late.get("start_row", 0)), int(late["rows"])))
        return out

    def learner_env(self, raw):
        """A raw vector env of the task as the learner sees it (scaled, the deadline's handling),
        its episodes counted for stable-baselines3's ``rollout/ep_rew_mean`` and ``ep_len_mean``."""
        from stable_baselines3.common.vec_env import VecMonitor

        return VecMonitor(LearnerEnv(ScaledVecEnv(raw, self.scaling), self.cfg.time_limit_terminal))

    def witnesses(self) -> Optional[Any]:
        """A new run's demonstration sequences from the oracle or the planner (:mod:`.demonstrations`),
        before the model is built. Their wall time counts as the run's, the time limit's included.
        None where the run has none."""
        from .demonstrations import DEMONSTRATION_STATE_SECONDS, longest, search, unavailable

        if self.cfg.demonstrations <= 0:
            why = unavailable(self.prog, self.cfg.algo)
            if why and get_preset(self.cfg.preset).demonstrations > 0:  # the preset's, withheld: say why
                self._tell(f"demonstrations: none ({why})")
            return None

        def check_stop() -> None:
            if self.stop.requested:
                raise KeyboardInterrupt

        imitated = self.cfg.imitation > 0
        found = search(self.prog, self.cfg.task, self.cfg.demonstrations, self.cfg.seed, self._tell, "before training",
                       state_seconds=IMITATION_STATE_SECONDS if imitated else DEMONSTRATION_STATE_SECONDS,
                       budget_seconds=self.cfg.imitation_seconds if imitated else self.cfg.demonstration_seconds,
                       time_limit=self.cfg.time_limit, check_stop=check_stop,
                       restarts=0 if imitated else None)
        if imitated:  # all of them, as they are: the actor imitates what it sees of the optimum
            return found
        return longest(found, self.cfg.demonstration_share, self.cfg.demonstration_repeat)

    def demonstrate(self, model, witnesses) -> dict:
        """The witnesses' transitions into ``model``'s replay buffer, told to the progress display."""
        from .demonstrations import add_demonstrations

        demos = add_demonstrations(self.prog, self.cfg.task, model, self.learner_env, self.scaling, witnesses,
                                   reward=self.cfg.reward, failure_reward=self.cfg.failure_reward)
        self.seconds_before += demos.seconds
        self.kept_rows = demos.rows
        set_imitation(model, self.cfg.imitation, self.kept_rows)
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
        was, self.failure_reward = self.failure_reward, self.cfg.failure_reward_at(gamma)
        self.env.venv.failure_reward = self.failure_reward  # the LearnerEnv under the VecMonitor
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
        # Not in the last validation interval (nor after the last step): nothing would learn from it.
        why = (None if self.late is None or self.time_up
               else self.late.due(self.curves, int(steps), self.cfg.steps, self.seconds, self.cfg.time_limit,
                                  interval=self.cfg.validate_every))
        if why is not None:
            add_late(self, model, int(steps), why)
        return row

    # -- checkpoints
    def state(self, model) -> dict:
        return {"steps": int(model.num_timesteps), "seconds": self.seconds, "best": self.best,
                "curves": self.curves, "late_demonstrations": None if self.late is None else self.late.added,
                "failed_starts": None if self.curriculum is None else self.curriculum.state(),
                "demonstration_rows": self.kept_rows, "learned": self.learned,
                "policy_search": None if self.search is None else asdict(self.search),
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
        self.schedule.restore(state, len(self.curves))
        if self.late is not None:  # added before the checkpoint: never again
            self.late.restore(state.get("late_demonstrations"))
            if self.late.gamma is not None:  # the model keeps its discount; the failure step's reward follows it
                self.set_discount(model, self.late.gamma)
        self.kept_rows = int(state.get("demonstration_rows") or 0)
        set_imitation(model, self.cfg.imitation, self.kept_rows)
        late_paths = None if self.late is None else self.late.imitated
        if late_paths is not None:  # the paths the late rule found, where it stored them
            set_imitation(model, late_paths["imitation"], late_paths["rows"], late_paths.get("start_row", 0))
        if self.curriculum is not None and state.get("failed_starts") is not None:
            self.curriculum.restore(state["failed_starts"])
        self.seconds_before = float(state["seconds"])
        self.learned = bool(state.get("learned", False))
        self.search = None if state.get("policy_search") is None else SearchState(**state["policy_search"])
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
            # Done for good (not a time limit's end, which a resume with more time continues, unless
            # the search takes the rest of the time).
            self.learned = not stopped and (int(model.num_timesteps) >= self.cfg.steps or self.plateau_step is not None
                                            or (self.time_up and self.cfg.policy_search is not None))
            if not stopped and (not self.curves or self.curves[-1]["steps"] != model.num_timesteps):
                self.validate(model, int(model.num_timesteps), getattr(model, "_logger", None))
            self.checkpoint(model)
        finally:
            if self.progress is not None:
                self.progress.finish()
        if self.plateau_step is not None:
            self._tell(f"validation stopped improving: the run ends at step {self.plateau_step:,} of "
                       f"{self.cfg.steps:,} (no gain over the latest {self.cfg.plateau:.0%} of its steps)")
        self._tell_no_search()
        if self.curves:
            spent = self.schedule.spent
            self._tell(f"validation: {len(self.curves)} times, {spent:.1f} s of the run's {self.seconds:.1f} s "
                       f"({spent / max(self.seconds, 1e-9):.0%})")
        return "interrupted" if stopped else "finished"

    # -- the policy search, after the learner
    def _tell_no_search(self) -> None:
        """Say why a run has not the preset's policy search (not when it was turned off)."""
        if self.cfg.policy_search is not None or not get_preset(self.cfg.preset).policy_search:
            return
        if self.prog.system.kind == "simulator":
            self._tell("policy search: none on a black box (its rollouts are too slow; --search-iterations N runs it)")
        elif (self.cfg.algo, self.cfg.engine) not in SEARCHABLE:
            self._tell(f"policy search: none (it searches the actor of SAC, TD3 or DDPG on sbx; this run trains "
                       f"{self.cfg.algo.upper()} on {self.cfg.engine})")

    def search_due(self, manifest: dict) -> bool:
        """Whether the run's policy search is still to do (its summary goes into the manifest at the end)."""
        return self.cfg.policy_search is not None and manifest.get("policy_search") is None and self.best is not None

    def policy_search(self, model) -> str:
        """Evolution strategies on the best model's actor (:mod:`.policy_search`), from where a
        checkpoint left it; the model the run keeps becomes the search's best only if it beats the
        learner's on validation. Checkpointed as the learner is; ``model`` (the learner's latest)
        is unchanged. Returns ``finished`` or ``interrupted``."""
        settings = SearchSettings.from_dict(self.cfg.policy_search)
        best = self.engine.load(self.cfg.algo, self.run.model_file())
        family = ActorFamily(best, self.cfg.algo, self.scaling)
        search = PolicySearch(self.prog, self.cfg.task, settings, family, self.validator, validation_score,
                              reward=self.cfg.reward, gamma=float(model.gamma), failure_reward=self.failure_reward,
                              seed=self.cfg.seed)
        if self.search is None:
            self.search = search.start(float(self.best["score"]))
        state = self.search
        self._tell(f"policy search: {settings.iterations:,} iterations of {settings.population} candidates on "
                   f"{settings.batch} new states each ({settings.objective}, perturbations of "
                   f"{settings.sigma * state.scale:.2g}, actions with gain {state.gain:g}), from the best model (validation score "
                   f"{self.best['score']:.4f}); at iteration {state.iteration:,}")
        limit = self.cfg.time_limit

        def after(state: SearchState) -> None:
            self.search = state
            if time.perf_counter() - self.last_checkpoint >= CHECKPOINT_SECONDS:
                self.checkpoint(model)

        state = search.run(state, lambda: self.stop.signal is not None or (limit is not None and self.seconds >= limit),
                           after)
        if self.stop.signal is not None:
            self.checkpoint(model)
            return "interrupted"
        self.search = state = search.finish(state, float(self.best["score"]))
        summary = json_safe(state.summary(self.best["score"]))
        kept = state.kept()
        if kept is not None:
            self.best = {**self.best, "score": kept["score"], "rates": kept["rates"], "return": kept["return"],
                         "seconds": round(self.seconds, 3), "search_iteration": state.best_iteration,
                         "action_gain": state.deployed_gain}
            family.install(best, state.best_theta)
            self.run.save_model(lambda path: best.save(str(path)), best=self.best, policy_search=summary)
            gain = f", its actions with gain {state.deployed_gain:g}" if state.deployed_gain != 1.0 else ""
            self._tell(f"policy search: kept iteration {state.best_iteration:,} of {state.iteration:,} (validation "
                       f"score {summary['score_before']:.4f} -> {state.kept_score:.4f}) in {state.seconds:.0f} s{gain}")
        else:
            self.run.update_manifest(policy_search=summary)
            self._tell(f"policy search: {state.iteration:,} iterations in {state.seconds:.0f} s, none beat the "
                       f"learner's model on validation; it stays")
        self.checkpoint(model)
        return "finished"


def _wrapper_base():
    from stable_baselines3.common.vec_env import VecEnvWrapper

    return VecEnvWrapper


class LearnerEnv(_wrapper_base()):
    """With the time left in the observation, the deadline ends a finite-horizon problem: the
    time-out is terminal (no bootstrapping past it). ``failure_reward`` (None: the env's) is a
    failure step's reward once the discount changed mid-run (:meth:`Session.set_discount`)."""

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
