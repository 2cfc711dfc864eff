"""stable-baselines3 glue: building and loading models, the scaled environment they train in, and
the controller that lets a trained policy act in :func:`asap_dsl.rollout.rollout`.

One :class:`Scaling` maps the environment's observations and actions to what the policy sees
(training wraps the vector env with it; the controller applies the same maps at evaluation), so a
policy is always judged on exactly the inputs it was trained on.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
from gymnasium import spaces

from asap_dsl.checker_common import ALGORITHMS

from .presets import OFF_POLICY

__all__ = ["PolicyController", "Scaling", "ScaledVecEnv", "build_model", "load_model"]


def _algo_class(algo: str):
    """The stable-baselines3 class of one of the language's algorithms (``sac`` is ``SAC``)."""
    import stable_baselines3

    if algo not in ALGORITHMS:
        raise ValueError(f"unknown algorithm '{algo}'; choose {', '.join(ALGORITHMS)}")
    return getattr(stable_baselines3, algo.upper())


@dataclass(frozen=True)
class Scaling:
    """Affine maps between the environment and the policy.

    Observations: each state entry becomes ``(s - centre) / half_width`` of its own box, the init
    box or the state space (:mod:`asap_dsl.observation` chooses per entry; the time entry of
    ``observe state, time`` is already in [0, 1]); actions: the policy's [-1, 1]^m onto the
    action bounds. ``observation = "none"`` and ``action = False`` are identities.

    ``gain`` (at least 1; with action scaling only) multiplies the policy's action before the
    clip onto [-1, 1]: actions within ``1 / gain`` of a bound saturate there. A squashed Gaussian's
    mean reaches its bounds only at infinity where minimum-time control rides them; the policy
    search chooses the gain a run's kept model acts with (``action_gain``, docs/training.md
    "The deployed action's gain"). Training itself always acts with gain 1.
    """

    obs_centre: np.ndarray
    obs_half: np.ndarray
    act_low: Optional[np.ndarray]
    act_high: Optional[np.ndarray]
    sources: tuple[str, ...] = ()  # per state entry: init, state or none
    gain: Any = 1.0  # a float, or per row [rows, 1] (the search judges several gains in one batch)

    @classmethod
    def for_system(cls, system, observation: str = "none", action: bool = False, init_box=None,
                   sources: Optional[Sequence[str]] = None) -> "Scaling":
        """``init_box``: the task's own initial box, if it has one; ``sources``: each entry's box
        as a run recorded it (default: :func:`asap_dsl.observation.observation_sources`)."""
        from asap_dsl.observation import _boxes, observation_sources

        n = system.n_state
        src = tuple(sources) if sources is not None else observation_sources(system, init_box, observation)
        if len(src) != n or set(src) - {"init", "state", "none"}:
            raise ValueError(f"the observation's scaling names {list(src)}, not one of init, state, none per state")
        (lo_i, hi_i), (lo_s, hi_s) = _boxes(system, init_box)
        lo = np.where(np.array(src) == "init", lo_i, lo_s)
        hi = np.where(np.array(src) == "init", hi_i, hi_s)
        scaled = np.array(src) != "none"
        with np.errstate(invalid="ignore", over="ignore"):
            centre = np.where(scaled, (lo + hi) / 2.0, 0.0)
            half = np.where(scaled, (hi - lo) / 2.0, 1.0)
        return cls(centre, half, system.action_low.copy() if action else None,
                   system.action_high.copy() if action else None, src)

    @classmethod
    def for_run(cls, system, config, init_box=None, gain: float = 1.0) -> "Scaling":
        """The scaling a run trained with: its recorded entries, or for a run from before they were
        recorded, the rule it was trained with (:func:`asap_dsl.observation.legacy_sources`);
        ``gain``: its kept model's action gain (1 while it trains)."""
        from asap_dsl.observation import legacy_sources

        recorded = getattr(config, "observation_sources", None)
        sources = (list(recorded.values()) if recorded is not None
                   else legacy_sources(system, init_box, config.observation_scaling))
        scaling = cls.for_system(system, config.observation_scaling, config.action_scaling, init_box, sources=sources)
        return scaling if gain == 1.0 else scaling.with_gain(gain)

    def with_gain(self, gain) -> "Scaling":
        """The same maps with the action multiplied by ``gain`` before its clip (ValueError where the
        actions are not scaled or the gain is not at least 1 and finite)."""
        from dataclasses import replace

        g = np.asarray(gain, dtype=np.float64)
        if not (np.all(np.isfinite(g)) and np.all(g >= 1.0)):
            raise ValueError(f"an action gain is a finite number of at least 1; got {gain!r}")
        if self.act_low is None and np.any(g != 1.0):
            raise ValueError("an action gain needs the actions scaled onto [-1, 1]")
        return replace(self, gain=gain)

    def observation(self, obs: np.ndarray) -> np.ndarray:
        o = np.array(obs, dtype=np.float32, copy=True)
        n = self.obs_centre.size
        o[..., :n] = ((o[..., :n] - self.obs_centre) / self.obs_half).astype(np.float32)
        return o

    def observation_space(self, space: spaces.Box) -> spaces.Box:
        n = self.obs_centre.size
        low, high = space.low.astype(np.float64).copy(), space.high.astype(np.float64).copy()
        with np.errstate(invalid="ignore", over="ignore"):
            low[:n] = (low[:n] - self.obs_centre) / self.obs_half
            high[:n] = (high[:n] - self.obs_centre) / self.obs_half
        f32 = float(np.finfo(np.float32).max)
        low, high = np.clip(low, -f32, f32), np.clip(high, -f32, f32)
        return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)

    def action(self, a: np.ndarray) -> np.ndarray:
        """The policy's action in the environment's units."""
        a = np.asarray(a, dtype=np.float64)
        if self.act_low is None:
            return a
        return self.act_low + (np.clip(self.gain * a, -1.0, 1.0) + 1.0) * 0.5 * (self.act_high - self.act_low)

    def policy_action(self, a: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`action`: the policy's action that the environment's action ``a``
        (within the bounds) is; the identity without action scaling."""
        a = np.asarray(a, dtype=np.float64)
        if self.act_low is None:
            return a
        width = self.act_high - self.act_low
        u = np.divide(2.0 * (a - self.act_low), width, out=np.ones_like(a), where=width > 0) - 1.0
        return np.clip(u, -1.0, 1.0) / self.gain

    def action_space(self, space: spaces.Box) -> spaces.Box:
        if self.act_low is None:
            return space
        return spaces.Box(-1.0, 1.0, shape=space.shape, dtype=np.float32)


def _wrapper_base():
    from stable_baselines3.common.vec_env import VecEnvWrapper

    return VecEnvWrapper


class ScaledVecEnv(_wrapper_base()):
    """The vector env as the policy sees it (observations and actions through a :class:`Scaling`)."""

    def __init__(self, venv, scaling: Scaling):
        self.scaling = scaling
        super().__init__(venv, observation_space=scaling.observation_space(venv.observation_space),
                         action_space=scaling.action_space(venv.action_space))

    def reset(self):
        return self.scaling.observation(self.venv.reset())

    def step_async(self, actions) -> None:
        self.venv.step_async(self.scaling.action(actions))

    def step_wait(self):
        obs, reward, done, infos = self.venv.step_wait()
        if done.any():
            for i in np.flatnonzero(done):
                infos[i]["terminal_observation"] = self.scaling.observation(infos[i]["terminal_observation"])
        return self.scaling.observation(obs), reward, done, infos


class PolicyController:
    """A trained policy as a controller: deterministic actions, one batched call per step."""

    def __init__(self, model, scaling: Scaling, deterministic: bool = True):
        self.model, self.scaling, self.deterministic = model, scaling, deterministic

    def reset(self, states: np.ndarray) -> None:
        pass

    def act(self, obs: np.ndarray, states: np.ndarray, t: int) -> np.ndarray:
        a, _ = self.model.predict(self.scaling.observation(obs), deterministic=self.deterministic)
        return self.scaling.action(a)


def model_kwargs(algo: str, action_space: spaces.Box, settings: dict[str, Any], engine: str = "sb3") -> dict[str, Any]:
    """The keywords of ``algo``'s model class on ``engine`` (stable-baselines3's own or sbx's) for
    the resolved hyperparameters ``settings``: the constructor's, the policy's in
    ``policy_kwargs`` (:func:`.hyper.split`), for TD3/DDPG ``action_noise`` as a number (the std of
    Gaussian exploration noise as a fraction of the action half-range) and for SAC
    ``target_entropy_per_action``."""
    from stable_baselines3.common.noise import NormalActionNoise

    from .hyper import split

    kw, policy = split(engine, algo, settings)
    noise = kw.pop("action_noise", None)
    per_action = kw.pop("target_entropy_per_action", None)
    m = action_space.shape[0]
    if per_action is not None and algo == "sac":  # "auto" is -1 per action dimension
        kw["target_entropy"] = float(per_action) * m
    if noise:
        half = (action_space.high - action_space.low) / 2.0
        kw["action_noise"] = NormalActionNoise(np.zeros(m), float(noise) * half.astype(np.float64))
    kw["policy_kwargs"] = policy
    if algo in OFF_POLICY:
        from .buffers import default_buffer

        buffer = default_buffer(kw)
        if buffer is not None:
            kw["replay_buffer_class"] = buffer
    return kw


def build_model(algo: str, env, settings: dict[str, Any], seed: int, tensorboard_log: Optional[str] = None):
    """A fresh stable-baselines3 model on torch; ``settings`` are the resolved hyperparameters
    (:func:`model_kwargs`). The engine of a run builds it: :mod:`.engines`."""
    cls = _algo_class(algo)
    kw = model_kwargs(algo, env.action_space, settings, "sb3")
    # stable-baselines3's own policies take no ``layer_norm``: true picks the project's, false nothing.
    policy = _layer_norm_policy(algo) if kw["policy_kwargs"].pop("layer_norm", False) else "MlpPolicy"
    return cls(policy, env, seed=seed, device="cpu", tensorboard_log=tensorboard_log, verbose=0, **kw)


#: The off-policy algorithms' policy classes whose critics can normalise their hidden layers.
_LAYER_NORM_BASES = {"sac": ("stable_baselines3.sac.policies", "SACPolicy"),
                     "td3": ("stable_baselines3.td3.policies", "TD3Policy"),
                     "ddpg": ("stable_baselines3.td3.policies", "TD3Policy")}
_layer_norm_classes: dict = {}


def _layer_norm_policy(algo: str):
    """stable-baselines3's policy of ``algo`` whose critics normalise every hidden layer
    (``layer_norm``): Linear, LayerNorm, activation, as sbx builds them, so that the setting means
    one thing on both engines. Defined on first use: it imports torch."""
    import importlib

    module, base_name = _LAYER_NORM_BASES[algo]
    name = "LayerNorm" + base_name
    if name not in _layer_norm_classes:
        from torch import nn

        base = getattr(importlib.import_module(module), base_name)

        def make_critic(self, features_extractor=None):
            critic = base.make_critic(self, features_extractor)
            for idx, q_net in enumerate(critic.q_networks):
                layers: list = []
                for m in q_net:  # a norm after every Linear but the output
                    layers.append(m)
                    if isinstance(m, nn.Linear) and m is not q_net[-1]:
                        layers.append(nn.LayerNorm(m.out_features))
                critic.q_networks[idx] = nn.Sequential(*layers).to(self.device)
                critic.add_module(f"qf{idx}", critic.q_networks[idx])
            return critic

        cls = type(name, (base,), {"make_critic": make_critic, "__module__": __name__, "__qualname__": name})
        _layer_norm_classes[name] = cls
    return _layer_norm_classes[name]


def __getattr__(name: str):
    # A saved model names its policy class by module and name: loading one finds it here.
    for algo, (_, base_name) in _LAYER_NORM_BASES.items():
        if name == "LayerNorm" + base_name:
            return _layer_norm_policy(algo)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def load_checked(cls, algo: str, path: Path, env=None):
    """``cls.load(path)`` once the zip's policy is of ``algo``'s kind (a pickle: only from a run
    directory the user named). A class's loader takes a zip of another algorithm (a hand-edited
    ``algo`` in run.json) and sbx's would then report a SAC policy as TD3's; TD3 and DDPG, PPO and
    A2C share a policy class, and the manifest alone tells them apart."""
    import zipfile

    from stable_baselines3.common.save_util import json_to_data

    with zipfile.ZipFile(path) as z:  # its "data" entry alone: the parameters are read once, by the load
        data = json_to_data(z.read("data").decode())
    held, expected = data.get("policy_class"), cls.policy_aliases["MlpPolicy"]
    if isinstance(held, type) and not issubclass(held, expected):
        raise ValueError(f"it holds a {held.__name__}, not the {expected.__name__} of {algo}: its manifest "
                         "names another algorithm")
    return cls.load(str(path), env=env, device="cpu")


def load_model(algo: str, path: Path, env=None):
    """Load a model saved by :func:`build_model`'s model, refused when it is of another algorithm."""
    return load_checked(_algo_class(algo), algo, path, env=env)
