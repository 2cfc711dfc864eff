"""Batched simulators: the system of a spec as ``reset(states [B, n])`` / ``step(actions [B, m])``.

The simulator protocol (docs/language.md, "Dynamics"), which ``simulator "package.module:factory"`` must return:

* attributes ``state_dim``, ``action_dim``, ``dt``;
* ``reset(states [B, n]) -> states [B, n]``: set every entry of the batch to the given state;
* ``step(actions [B, m]) -> states [B, n]``: advance every entry by ``dt``.

The factory is called when an environment or simulator is built (never when a spec is loaded
or linted): as ``factory(batch=B)`` if it accepts a ``batch`` argument (or ``**kwargs``), else as
``factory()``, in which case the object must accept any batch size. Built-in simulators also take
``reset(states, mask=...)`` to reset only some entries; a user simulator is reset whole, with the
other entries given their current states.

Every simulator built here is wrapped in :class:`CheckedSimulator`, which clips actions to the
spec's action bounds, checks shapes, and turns any failure of the user's code into a
:class:`SimulatorError` naming the spec file and the line of its ``simulator`` statement.
"""

from __future__ import annotations

import importlib
import inspect
import os
from typing import Any, Callable, Optional

import numpy as np

from ..dynamics import numpy_step
from ..model import SystemModel

__all__ = ["SimulatorError", "CheckedSimulator", "OdeSimulator", "build_simulator", "register_simulator",
           "registered_simulators"]


# A factory or simulator is the user's trusted code, but whatever it raises — sys.exit() included,
# which `except Exception` would let end the process silently with status 0 — is reported.
_USER_FAILURES = (Exception, SystemExit)


class SimulatorError(RuntimeError):
    """A simulator could not be built or misbehaved; the message names the spec line."""


_REGISTRY: dict[str, Callable[..., Any]] = {}


def register_simulator(name: str, factory: Callable[..., Any]) -> None:
    """Make ``simulator "NAME"`` resolve to ``factory(batch=B)``."""
    _REGISTRY[name] = factory


def registered_simulators() -> tuple[str, ...]:
    return tuple(sorted(_REGISTRY))


def _swimmer(batch: int = 1):
    from .mujoco_swimmer import MujocoSwimmer

    return MujocoSwimmer(batch)


register_simulator("mujoco:swimmer", _swimmer)


def _seconds(system: SystemModel) -> Optional[float]:
    """The system's ``dt`` as a float; None for a map without ``dt`` (its spec counts in steps)."""
    return None if system.dt is None else float(system.dt)


class OdeSimulator:
    """An ``ode`` or ``map`` system, discretised by :func:`asap_dsl.dynamics.numpy_step`."""

    supports_mask = True

    def __init__(self, system: SystemModel, batch: int = 1):
        self.system = system
        self._step = numpy_step(system)
        self.state_dim, self.action_dim, self.dt = system.n_state, system.n_action, _seconds(system)
        self.batch = int(batch)
        self.states = np.zeros((self.batch, self.state_dim))

    def reset(self, states: np.ndarray, mask: Optional[np.ndarray] = None) -> np.ndarray:
        states = np.asarray(states, dtype=np.float64)
        if mask is None:
            self.states = states.copy()
        else:
            self.states[mask] = states[mask]
        return self.states.copy()

    def step(self, actions: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):  # a diverging ODE becomes inf/nan; the env ends it cleanly
            self.states = np.asarray(self._step(self.states, actions), dtype=np.float64)
        return self.states.copy()


def _where(system: SystemModel, file: Optional[str]) -> str:
    span = system.dynamics_span
    return f"{file or '<spec>'}:{span.line}:{span.column}"


class CheckedSimulator:
    """Validates a simulator against the spec, clips actions, and names the spec line on failure."""

    def __init__(self, inner: Any, system: SystemModel, batch: int, file: Optional[str] = None, user: bool = False):
        self.inner, self.system, self.batch, self.user = inner, system, int(batch), user
        self.where = _where(system, file)
        self.state_dim, self.action_dim, self.dt = system.n_state, system.n_action, _seconds(system)
        self.action_low, self.action_high = system.action_low, system.action_high
        self.supports_mask = bool(getattr(inner, "supports_mask", False))
        self._check_attributes()

    def _fail(self, what: str) -> SimulatorError:
        return SimulatorError(f"{self.where}: simulator \"{self.system.simulator or self.system.kind}\": {what}")

    def _check_attributes(self) -> None:
        inner = self.inner
        missing = [a for a in ("state_dim", "action_dim", "dt", "reset", "step") if not hasattr(inner, a)]
        if missing:
            raise self._fail(f"the object {type(inner).__name__} lacks {', '.join(missing)} (the simulator protocol "
                             "needs state_dim, action_dim, dt, reset(states) and step(actions))")
        for a in ("reset", "step"):
            if not callable(getattr(inner, a)):
                raise self._fail(f"{a} is not callable")
        try:
            sd, ad = int(inner.state_dim), int(inner.action_dim)
            dt = None if self.system.dt is None else float(inner.dt)  # None: a map that counts in steps
        except (TypeError, ValueError) as err:
            raise self._fail(f"state_dim, action_dim and dt must be numbers ({err})") from None
        if sd != self.system.n_state:
            raise self._fail(f"its state_dim is {sd} but the system declares {self.system.n_state} state(s) "
                             f"({', '.join(self.system.state_names)})")
        if ad != self.system.n_action:
            raise self._fail(f"its action_dim is {ad} but the system declares {self.system.n_action} action(s) "
                             f"({', '.join(self.system.action_names)})")
        if dt is not None and not np.isclose(dt, self.system.dt, rtol=1e-9, atol=1e-12):
            raise self._fail(f"its dt is {dt:g} s but the spec says dt = {self.system.dt:g}")

    def _check_out(self, out: Any, call: str) -> np.ndarray:
        try:
            arr = np.asarray(out, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise self._fail(f"{call} returned something that is not an array of numbers ({err})") from None
        if arr.shape != (self.batch, self.state_dim):
            raise self._fail(f"{call} returned shape {arr.shape}; expected ({self.batch}, {self.state_dim}) "
                             "= [batch, state_dim]")
        return arr

    def reset(self, states: np.ndarray, mask: Optional[np.ndarray] = None) -> np.ndarray:
        states = np.asarray(states, dtype=np.float64)
        try:
            if self.supports_mask:
                out = self.inner.reset(states, mask=mask)
            else:
                out = self.inner.reset(states)
        except SimulatorError:
            raise
        except _USER_FAILURES as err:  # noqa: BLE001 — the user's code: report where it is declared
            raise self._fail(f"reset raised {type(err).__name__}: {err}") from err
        return self._check_out(out, "reset")

    def step(self, actions: np.ndarray) -> np.ndarray:
        a = np.clip(np.asarray(actions, dtype=np.float64), self.action_low, self.action_high)
        try:
            with np.errstate(all="ignore"):
                out = self.inner.step(a)
        except SimulatorError:
            raise
        except _USER_FAILURES as err:  # noqa: BLE001
            raise self._fail(f"step raised {type(err).__name__}: {err}") from err
        return self._check_out(out, "step")


def _call_factory(factory: Callable[..., Any], batch: int) -> Any:
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        params = {}
    takes_batch = "batch" in params or any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    return factory(batch=batch) if takes_batch else factory()


def build_simulator(system: SystemModel, batch: int = 1, file: Optional[str] = None) -> CheckedSimulator:
    """The batched simulator of ``system`` (ode/map, a registered name, or a user factory)."""
    if system.kind in ("ode", "map"):
        return CheckedSimulator(OdeSimulator(system, batch), system, batch, file)
    target = system.simulator or ""
    where = _where(system, file)
    if target in _REGISTRY:
        try:
            inner = _REGISTRY[target](batch=batch)
        except _USER_FAILURES as err:  # noqa: BLE001
            raise SimulatorError(f"{where}: simulator \"{target}\" could not be built: {type(err).__name__}: {err}") from err
        return CheckedSimulator(inner, system, batch, file)
    if ":" not in target:
        known = ", ".join(f'"{n}"' for n in registered_simulators())
        raise SimulatorError(f"{where}: simulator \"{target}\" is not registered (known: {known}) and is not "
                             "\"package.module:factory\"")
    _probe_once(where, target, batch)
    return CheckedSimulator(_user_factory(where, target, batch), system, batch, file, user=True)


def _user_factory(where: str, target: str, batch: int) -> Any:
    """Import ``package.module:factory`` and call it; every failure is one SimulatorError."""
    module_name, attr = target.split(":", 1)
    try:
        module = importlib.import_module(module_name)
    except _USER_FAILURES as err:  # noqa: BLE001 — ImportError, or the module's own errors
        raise SimulatorError(f"{where}: simulator \"{target}\": cannot import module '{module_name}': "
                             f"{type(err).__name__}: {err}") from err
    factory: Any = module
    for part in attr.split("."):
        if not hasattr(factory, part):
            raise SimulatorError(f"{where}: simulator \"{target}\": module '{module_name}' has no attribute '{attr}'")
        factory = getattr(factory, part)
    if not callable(factory):
        raise SimulatorError(f"{where}: simulator \"{target}\": '{attr}' is not callable (a factory returning a "
                             "simulator is expected)")
    try:
        return _call_factory(factory, batch)
    except _USER_FAILURES as err:  # noqa: BLE001
        raise SimulatorError(f"{where}: simulator \"{target}\": the factory raised {type(err).__name__}: {err}") from err


_PROBED: set[tuple[str, int]] = set()
_PROBE_SECONDS = 120.0


def _probe_once(where: str, target: str, batch: int) -> None:
    """Build the user's simulator once in a forked child first, so that a factory which ends its
    process (``os.abort()``, ``os._exit``, a crash in native code) is one sentence here instead of
    a silent death of asapc. A Python exception is left to the in-process build, which words it;
    a child that cannot finish in time (a lock held across the fork) is not held against the factory."""
    if (target, batch) in _PROBED or not hasattr(os, "fork"):
        return
    _PROBED.add((target, batch))
    import signal
    import time
    import warnings

    with warnings.catch_warnings():  # the child only imports and calls the factory, then leaves
        warnings.simplefilter("ignore", RuntimeWarning)
        pid = os.fork()
    if pid == 0:  # the child: never returns into the caller's code
        code = 3
        try:
            _user_factory(where, target, batch)
            code = 0
        except BaseException:  # noqa: BLE001 — reported by the parent's own build
            pass
        os._exit(code)
    deadline = time.monotonic() + _PROBE_SECONDS
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return
        time.sleep(0.01)
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        try:
            name = signal.Signals(sig).name
        except ValueError:
            name = f"signal {sig}"
        raise SimulatorError(f"{where}: simulator \"{target}\": building it killed its process ({name})")
    if os.WIFEXITED(status) and os.WEXITSTATUS(status) not in (0, 3):
        raise SimulatorError(f"{where}: simulator \"{target}\": building it ended its process "
                             f"(exit status {os.WEXITSTATUS(status)})")
