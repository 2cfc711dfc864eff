"""Training engines: the library that computes a run's policy updates.

* ``sb3`` — stable-baselines3 on torch, the reference: every algorithm of the language, and the
  ``paper`` preset's engine.
* ``sbx`` — sbx-rl: stable-baselines3's algorithms and API on JAX, each update compiled by XLA
  (SAC, TD3, DDPG and PPO; it has no A2C). The ``default`` preset's engine where it has the
  algorithm.

Both run stable-baselines3's own loop — vector env, callbacks, replay and rollout buffers, the
zip format, ``predict`` — so the run directory, checkpoints, validation, evaluation and sweeps do
not depend on the engine. What does is here, one class per engine: its model classes, how the
resolved settings become a model, how one is loaded, and the learner's random state a
checkpoint keeps. Nothing here imports torch or JAX until a model is built or loaded.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path
from typing import Any, Optional

import numpy as np

from asap_dsl.checker_common import ALGORITHMS

__all__ = ["ENGINES", "REFERENCE", "Engine", "choose_engine", "get_engine"]

#: The engine every algorithm has, and the one runs recorded before engines existed used.
REFERENCE = "sb3"


class Engine:
    """A library with stable-baselines3's API that trains the algorithms it has."""

    name: str = ""
    description: str = ""
    algorithms: tuple[str, ...] = ()
    module: str = ""    # what it imports as
    package: str = ""   # what pip installs

    def runs(self, algo: str) -> bool:
        return algo in self.algorithms

    def available(self) -> bool:
        """Installed (checked without importing it)."""
        return importlib.util.find_spec(self.module) is not None

    def build(self, algo: str, env, settings: dict[str, Any], seed: int, tensorboard_log: Optional[str] = None):
        """A fresh model of ``algo`` on ``env`` with the resolved ``settings`` (see
        :func:`~asap_dsl.backends.rl.sb3.model_kwargs` for what they mean)."""
        raise NotImplementedError

    def load(self, algo: str, path: Path, env=None):
        """A model saved by a model of this engine (a pickle: only from a run directory the user
        named)."""
        raise NotImplementedError

    def rng_state(self, model) -> dict:
        """The learner's random state beyond Python's, numpy's and the environment's."""
        raise NotImplementedError

    def set_rng_state(self, model, state: dict) -> None:
        raise NotImplementedError


class SB3Engine(Engine):
    name = "sb3"
    description = "stable-baselines3 on torch (the reference)"
    algorithms = ALGORITHMS
    module = "stable_baselines3"
    package = "stable-baselines3"

    def build(self, algo, env, settings, seed, tensorboard_log=None):
        from .sb3 import build_model

        return build_model(algo, env, settings, seed, tensorboard_log=tensorboard_log)

    def load(self, algo, path, env=None):
        from .sb3 import load_model

        return load_model(algo, path, env=env)

    def rng_state(self, model) -> dict:
        import torch

        return {"torch": torch.get_rng_state()}

    def set_rng_state(self, model, state: dict) -> None:
        import torch

        torch.set_rng_state(state["torch"])


# One compute thread per process, as the sweep gives torch: the updates of the networks this
# project trains (64 x 64, batch 256) are too small for XLA's intra-op threads to pay, and a
# second thread would take the core another run or the environment needs.
_XLA_FLAG = "--xla_cpu_multi_thread_eigen=false"


def _configure_jax() -> None:
    """Before JAX loads (it reads these once, at import): CPU only, one compute thread, and the
    compiled programs kept on disk. What the environment already sets stands."""
    if "jax" in sys.modules:
        return  # loaded by the caller already: its settings stand
    from asap_dsl.native.cache import cache_dir

    env = os.environ
    env.setdefault("JAX_PLATFORMS", "cpu")
    flags = env.get("XLA_FLAGS", "")
    if "xla_cpu_multi_thread_eigen" not in flags:
        env["XLA_FLAGS"] = f"{flags} {_XLA_FLAG}".strip()
    # Building a model compiles some seventy small XLA programs (flax runs every initialiser
    # eagerly), and the first updates and predictions more: about 12 s of CPU per process. From the
    # disk a second start loads them in about 1.5 s. The cache evicts the least recently used.
    if "JAX_COMPILATION_CACHE_DIR" not in env:
        jax_dir = cache_dir() / "jax"
        try:
            jax_dir.mkdir(parents=True, exist_ok=True)
            usable = os.access(jax_dir, os.W_OK | os.X_OK)
        except OSError:  # $ASAP_CACHE_DIR a file, a read-only disk: compile each time, without JAX's warnings
            usable = False
        if not usable:
            return
        env["JAX_COMPILATION_CACHE_DIR"] = str(jax_dir)
    env.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    env.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
    env.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(256 << 20))


def _fused_sac_policy():
    """sbx's SAC policy drawing an exploration action in one compiled call: sbx splits the key
    (one XLA program) and then samples (another); fused, the same keys and actions cost one
    dispatch, about 120 us less per vector step. Defined on first use: it imports JAX."""
    global _FusedSACPolicy
    if _FusedSACPolicy is None:
        import jax
        from sbx.sac.policies import SACPolicy

        @jax.jit
        def sample(actor_state, observations, key):
            key, noise_key = jax.random.split(key, 2)  # SACPolicy.reset_noise, then sample_action
            action = actor_state.apply_fn(actor_state.params, observations).sample(seed=noise_key)
            return action, key, noise_key

        class FusedSACPolicy(SACPolicy):
            def _predict(self, observation, deterministic: bool = False):
                if deterministic or self.use_sde:
                    return super()._predict(observation, deterministic=deterministic)
                action, self.key, self.noise_key = sample(self.actor_state, observation, self.key)
                return action

        FusedSACPolicy.__module__ = __name__
        FusedSACPolicy.__qualname__ = "FusedSACPolicy"
        _FusedSACPolicy = FusedSACPolicy
    return _FusedSACPolicy


_FusedSACPolicy = None


def __getattr__(name: str):
    # A saved model names its policy class by module and name: loading one finds it here.
    if name == "FusedSACPolicy":
        return _fused_sac_policy()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class SbxEngine(Engine):
    name = "sbx"
    description = "sbx-rl: stable-baselines3's algorithms on JAX (no A2C)"
    algorithms = ("sac", "td3", "ddpg", "ppo")
    module = "sbx"
    package = "sbx-rl"

    def _model_class(self, algo: str):
        if not self.runs(algo):
            raise ValueError(f"the {self.name} engine has no {algo}")
        _configure_jax()
        if algo == "sac":  # sbx's SAC, which imitates the oracle's paths when a run asks (:mod:`.imitation`)
            from .imitation import imitating_sac

            return imitating_sac()
        import sbx

        return getattr(sbx, algo.upper())

    def build(self, algo, env, settings, seed, tensorboard_log=None):
        from .sb3 import model_kwargs

        kw = model_kwargs(algo, env.action_space, settings, self.name)
        if algo == "ddpg":
            kw.setdefault("qf_learning_rate", None)  # sbx's DDPG defaults the critic to 1e-3; SB3 uses one rate
        if algo == "ppo":
            # SB3's PPO starts the action head orthogonal with gain 0.01 (actions near the centre);
            # sbx does that only when asked.
            kw["policy_kwargs"].setdefault("ortho_init", True)
        cls = self._model_class(algo)
        policy = _fused_sac_policy() if algo == "sac" else "MlpPolicy"
        return cls(policy, env, seed=seed, tensorboard_log=tensorboard_log, verbose=0, **kw)

    def load(self, algo, path, env=None):
        from .sb3 import load_checked

        return load_checked(self._model_class(algo), algo, path, env=env)

    # The keys are raw uint32 pairs (jax.random.PRNGKey). The model's drives the updates and is
    # re-seeded when a model loads; the policy's draw exploration and are pickled with it.
    def rng_state(self, model) -> dict:
        policy = model.policy
        return {"jax": {"model": np.asarray(model.key), "policy": np.asarray(policy.key),
                        "noise": np.asarray(policy.noise_key)}}

    def set_rng_state(self, model, state: dict) -> None:
        import jax.numpy as jnp

        keys = state["jax"]
        model.key = jnp.asarray(keys["model"])
        model.policy.key = jnp.asarray(keys["policy"])
        model.policy.noise_key = jnp.asarray(keys["noise"])


_ENGINES: dict[str, Engine] = {e.name: e for e in (SbxEngine(), SB3Engine())}
ENGINES = tuple(_ENGINES)


def get_engine(name: str) -> Engine:
    """The engine of that name; ``KeyError`` naming the known ones otherwise."""
    try:
        return _ENGINES[name]
    except KeyError:
        raise KeyError(f"unknown engine '{name}'; choose {' or '.join(ENGINES)}") from None


def choose_engine(explicit: Optional[str], preferred: str, algo: str) -> str:
    """The engine of a run of ``algo``: ``explicit`` if given (``ValueError`` in one sentence when
    it cannot run it), else the preset's ``preferred`` one where it has the algorithm and is
    installed, else the reference."""
    if explicit is None:
        e = get_engine(preferred)
        return e.name if e.runs(algo) and e.available() else REFERENCE
    try:
        e = get_engine(explicit)
    except KeyError as err:
        raise ValueError(err.args[0]) from None
    if not e.runs(algo):
        others = [n for n, o in _ENGINES.items() if o.runs(algo)]
        raise ValueError(f"the {e.name} engine has no {algo} (it trains {', '.join(e.algorithms)}); "
                         f"use the {' or '.join(others)} engine")
    if not e.available():
        raise ValueError(f"the {e.name} engine needs the {e.package} package: pip install {e.package}")
    return e.name
