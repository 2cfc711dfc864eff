"""The MuJoCo swimmer of gymnasium's ``Swimmer-v5``, batched over B simulations.

Physics as gymnasium ships it (``gymnasium/envs/mujoco/assets/swimmer.xml``: timestep 0.01 s,
RK4) with ``frame_skip`` 4, so one step is 0.04 s. The state is ``concat(qpos, qvel)`` (10 numbers:
``x, y, theta_tip, theta_1, theta_2, vx, vy, w_tip, w_1, w_2``), which is gymnasium's observation
with ``exclude_current_positions_from_observation=False``. Any state is set through ``qpos`` /
``qvel`` after a reset of the simulation (``mj_resetData``); actions are clipped to the actuators'
``[-1, 1]``.

Stepping: with MuJoCo >= 4.0 the B simulations live in a :class:`mujoco.batch.Batch`, which steps
them in C on a thread pool (the GIL released), bit-identical to calling ``mj_step`` on one ``MjData``
per simulation, which is what this module does on older MuJoCo. Each simulation keeps its whole
integration state between steps (``qacc_warmstart`` included, which the joint-limit solver starts
from), as gymnasium's env does. Threads: all available CPUs for batches of at least
``MIN_BATCH_PER_THREAD`` per thread, else the calling thread only; the environment variable
``ASAP_DSL_MUJOCO_THREADS`` (or the ``nthread`` argument) overrides this.
"""

from __future__ import annotations

import os
from typing import Optional

import numpy as np

FRAME_SKIP = 4
MIN_BATCH_PER_THREAD = 8  # below this, thread hand-offs cost more than they save
THREADS_ENV = "ASAP_DSL_MUJOCO_THREADS"


def swimmer_xml_path() -> str:
    """The swimmer model shipped inside gymnasium."""
    import gymnasium

    path = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", "swimmer.xml")
    if not os.path.exists(path):
        raise FileNotFoundError(f"gymnasium does not ship {path}; reinstall gymnasium with its MuJoCo assets")
    return path


def _available_cpus() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def default_threads(batch: int) -> int:
    """Threads for a batch of ``batch`` simulations: ``ASAP_DSL_MUJOCO_THREADS``, else by size."""
    env = os.environ.get(THREADS_ENV, "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            raise ValueError(f"{THREADS_ENV} must be a positive integer, got {env!r}") from None
        if n < 1:
            raise ValueError(f"{THREADS_ENV} must be a positive integer, got {env!r}")
        return min(n, max(1, batch))
    return max(1, min(_available_cpus(), batch // MIN_BATCH_PER_THREAD))


def _mujoco_batch():
    """The module ``mujoco.batch`` (MuJoCo >= 4.0), else None."""
    try:
        from mujoco import batch
    except ImportError:
        return None
    return batch


class MujocoSwimmer:
    """``reset(states [B, 10]) -> states``, ``step(actions [B, 2]) -> states``; ``dt = 0.04``."""

    supports_mask = True

    def __init__(self, batch: int = 1, frame_skip: int = FRAME_SKIP, nthread: Optional[int] = None):
        import mujoco

        self._mj = mujoco
        self.model = mujoco.MjModel.from_xml_path(swimmer_xml_path())
        self.frame_skip = int(frame_skip)
        self.nq, self.nv = self.model.nq, self.model.nv
        self.state_dim = self.nq + self.nv
        self.action_dim = self.model.nu
        self.dt = float(self.model.opt.timestep) * self.frame_skip
        self.ctrl_low = self.model.actuator_ctrlrange[:, 0].copy()
        self.ctrl_high = self.model.actuator_ctrlrange[:, 1].copy()
        self.batch = int(batch)
        self.nthread = default_threads(self.batch) if nthread is None else max(1, int(nthread))
        mj_batch = _mujoco_batch()
        if mj_batch is not None:
            self._batch = mj_batch.Batch(self.model, nsim=self.batch, nthread=self.nthread)
            # live (B, .) views of the state rows: writes are each simulation's state at its next call
            self._qpos, self._qvel = self._batch.bind("qpos"), self._batch.bind("qvel")
            self._ctrl = self._batch.bind("ctrl")
            self.data = None
        else:  # one MjData per simulation, stepped in turn
            self._batch = None
            self.nthread = 1
            self.data = [mujoco.MjData(self.model) for _ in range(self.batch)]
            self._qpos = np.zeros((self.batch, self.nq))
            self._qvel = np.zeros((self.batch, self.nv))

    def _states(self) -> np.ndarray:
        return np.concatenate((self._qpos, self._qvel), axis=1)

    def reset(self, states: np.ndarray, mask: Optional[np.ndarray] = None) -> np.ndarray:
        states = np.asarray(states, dtype=np.float64)
        rows = None if mask is None else np.flatnonzero(mask)
        if rows is not None and rows.size == 0:
            return self._states()
        if self._batch is not None:
            # mj_resetData per simulation (time, ctrl, warm start zeroed), then the new qpos / qvel;
            # no mj_forward: it would not change the state, and mj_step recomputes from it
            self._batch.reset(rows, stage=self._mj.mjtStage.mjSTAGE_NONE.value)
            sel = slice(None) if rows is None else rows
            self._qpos[sel] = states[sel, : self.nq]
            self._qvel[sel] = states[sel, self.nq:]
        else:
            for i in range(self.batch) if rows is None else rows:
                d = self.data[i]
                self._mj.mj_resetData(self.model, d)
                d.qpos[:] = states[i, : self.nq]
                d.qvel[:] = states[i, self.nq:]
                self._mj.mj_forward(self.model, d)
                self._qpos[i], self._qvel[i] = d.qpos, d.qvel
        return self._states()

    def step(self, actions: np.ndarray) -> np.ndarray:
        a = np.clip(np.asarray(actions, dtype=np.float64), self.ctrl_low, self.ctrl_high)
        if self._batch is not None:
            self._ctrl[:] = a
            self._batch.step(nstep=self.frame_skip)
        else:
            mj_step, model, n = self._mj.mj_step, self.model, self.frame_skip
            for i, d in enumerate(self.data):
                d.ctrl[:] = a[i]
                mj_step(model, d, n)
                self._qpos[i], self._qvel[i] = d.qpos, d.qvel
        return self._states()
