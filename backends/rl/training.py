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

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Protocol, Sequence, Union

from asap_dsl.program import Program, load
from asap_dsl.processes import Interrupts
from asap_dsl.runs import (Checkpoint, RunDir, RunError, check_target, create_run, default_run_name,
                           json_safe, package_versions, spec_hash, stamp)

from .config import ConfigError, TrainConfig, resolve_config
from .presets import OFF_POLICY
from . import hyper as _hyper
from .session import Session
from .validation import validation_score

__all__ = ["TrainProgress", "TrainResult", "train", "validation_score"]



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
        if name == "search_iterations":  # stored as the search's settings
            if fresh.policy_search != stored.policy_search:
                had = (stored.policy_search or {}).get("iterations", 0)
                out.append(f"--search-iterations {value} (the run has {had})")
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
          demonstrations: Optional[int] = None, failed_starts: Optional[float] = None,
          imitation: Optional[float] = None, search_iterations: Optional[int] = None) -> TrainResult:
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
    :param imitation: the weight of the actor's imitation of the oracle's paths
        (:mod:`asap_dsl.backends.rl.imitation`: SAC on the sbx engine, known dynamics; default: the
        preset's, 0 in both; 0: none). Its paths are the ``demonstrations`` states', or the preset's
        ``imitation_states``, all of them in the replay buffer from the start.
    :param search_iterations: the policy search's iterations after the learner (evolution
        strategies on the best actor, :mod:`asap_dsl.backends.rl.policy_search`; default: the
        preset's; 0: none). Its model is kept only if it beats the learner's on validation.
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
                             engine=engine, demonstrations=demonstrations, failed_starts=failed_starts,
                             imitation=imitation, search_iterations=search_iterations)
        _check_memory(prog, cfg)
        run = RunDir(out if out is not None else Path(runs_dir) / default_run_name(prog.file, cfg.task, cfg.algo,
                                                                                 cfg.reward, cfg.seed))
        given = {"task": task, "algo": algo, "engine": engine, "reward": reward, "seed": seed, "preset": preset,
                 "n_envs": n_envs, "demonstrations": demonstrations,
                 "failed_starts": failed_starts, "imitation": imitation, "search_iterations": search_iterations,
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
        search = cfg.policy_search
        if search:  # its population's rollouts, one batched environment
            check_batch(prog, cfg.task, search["population"] * search["batch"],
                        f"the policy search's {search['population']} x {search['batch']} rollouts", cfg.reward,
                        4 * 3 * width)
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
        session = Session(prog, cfg, run, progress, callbacks, stop)
        with run.guard():
            model = session.restore(ckpt)
            m = run.read_manifest()
            # The learner is done at its steps (a resume may raise them) or its plateau, or while the
            # policy search it handed over to is under way (in a time-limited run it takes the rest
            # of the time).
            ended = m["status"] == "finished" or session.learned
            searching = session.search is not None and m.get("policy_search") is None
            session.learned = ended and (cfg.steps <= int(model.num_timesteps) or "plateau_step" in m
                                         or (session.learned and searching))
            if session.learned and not session.search_due(m):
                return _finished(run, cfg, session, evaluate)
            again = {}
            if not session.learned and session.search is not None:  # more steps: a new search after them
                session.search, again = None, {"policy_search": None}
            run.update_manifest(status="running", config=cfg.to_dict(), error=None, **again)
    else:
        if check_target(run.path, force) or run.path.is_dir():  # refused before anything is built
            run.acquire(exclusive=True)  # the run it replaces (or the empty directory) is ours until then
        session = Session(prog, cfg, run, progress, callbacks, stop)
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
            status = "finished" if session.learned else session.learn(model)
            if status == "finished" and session.learned and session.search_due(run.read_manifest()):
                status = session.policy_search(model)
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


def _finished(run: RunDir, cfg: TrainConfig, session: Session, evaluate: bool) -> TrainResult:
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
