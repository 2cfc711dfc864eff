"""The MuJoCo swimmer of gymnasium's ``Swimmer-v5``, batched over B copies of ``MjData``.

Physics as gymnasium ships it (``gymnasium/envs/mujoco/assets/swimmer.xml``: timestep 0.01 s,
RK4) with ``frame_skip`` 4, so one step is 0.04 s. The state is ``concat(qpos, qvel)`` (10 numbers:
``x, y, theta_tip, theta_1, theta_2, vx, vy, w_tip, w_1, w_2``), which is gymnasium's observation
with ``exclude_current_positions_from_observation=False``. Any state is set through ``qpos`` /
``qvel`` followed by ``mj_forward``; actions are clipped to the actuators' ``[-1, 1]``.
"""

from __future__ import annotations

import os
from typing import Optional

import numpy as np

FRAME_SKIP = 4


def swimmer_xml_path() -> str:
    """The swimmer model shipped inside gymnasium."""
    import gymnasium

    path = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", "swimmer.xml")
    if not os.path.exists(path):
        raise FileNotFoundError(f"gymnasium does not ship {path}; reinstall gymnasium with its MuJoCo assets")
    return path


class MujocoSwimmer:
    """``reset(states [B, 10]) -> states``, ``step(actions [B, 2]) -> states``; ``dt = 0.04``."""

    supports_mask = True

    def __init__(self, batch: int = 1, frame_skip: int = FRAME_SKIP):
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
        self.data = [mujoco.MjData(self.model) for _ in range(self.batch)]
        self._states = np.zeros((self.batch, self.state_dim))

    def _read(self, i: int) -> None:
        d = self.data[i]
        self._states[i, : self.nq] = d.qpos
        self._states[i, self.nq:] = d.qvel

    def reset(self, states: np.ndarray, mask: Optional[np.ndarray] = None) -> np.ndarray:
        states = np.asarray(states, dtype=np.float64)
        rows = range(self.batch) if mask is None else np.flatnonzero(mask)
        for i in rows:
            d = self.data[i]
            self._mj.mj_resetData(self.model, d)
            d.qpos[:] = states[i, : self.nq]
            d.qvel[:] = states[i, self.nq:]
            self._mj.mj_forward(self.model, d)
            self._read(i)
        return self._states.copy()

    def step(self, actions: np.ndarray) -> np.ndarray:
        a = np.clip(np.asarray(actions, dtype=np.float64), self.ctrl_low, self.ctrl_high)
        mj_step, model, n = self._mj.mj_step, self.model, self.frame_skip
        for i, d in enumerate(self.data):
            d.ctrl[:] = a[i]
            mj_step(model, d, n)
            self._read(i)
        return self._states.copy()
