"""Watching a task: frames of its states, for ``render_mode="rgb_array"`` / ``"human"`` of the
environments (:mod:`asap_dsl.env`) and ``asapc eval RUN --video FILE``.

* The MuJoCo swimmer is drawn by MuJoCo's own offscreen renderer. Headless, that needs an OpenGL
  context without a display: EGL (Debian's ``libegl1`` with Mesa's ``libegl-mesa0``), else OSMesa
  (``libosmesa6``); with a display, GLFW first. ``MUJOCO_GL`` chooses one. The context is chosen
  when the first renderer is built, whatever imported MuJoCo before (its choice at import time
  would be GLFW, which has no display here).
* Every other system (ode, map, a user's simulator) is drawn as a frame of the state-space
  picture of :mod:`asap_dsl.backends.compare.phase_plots`: the projection that shows the task, its
  goal and unsafe regions and initial box, the path since the episode began and the current state
  (matplotlib's Agg, no display needed).

``"human"`` shows the same frames in a matplotlib window, where there is a display. A renderer
that cannot be had is :class:`RenderError`, one sentence saying why and what to install.
"""

from __future__ import annotations

import importlib
import os
import warnings
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

__all__ = ["RENDER_MODES", "RenderError", "Renderer", "make_renderer", "mujoco_gl", "write_video"]

RENDER_MODES = ("rgb_array", "human")
SIZE = (640, 480)  # pixels of a MuJoCo frame: multiples of 16, as H.264's macroblocks want
PANEL_PX = 480     # pixels per state-space panel (square), and its height
DPI = 80
_GL: dict[str, object] = {}  # the OpenGL context class chosen, once per process


class RenderError(RuntimeError):
    """No renderer can be had (no OpenGL context for MuJoCo, no display for ``human``): the
    message says why, in one sentence."""


# ---------------------------------------------------------------------------------- MuJoCo
def _gl_candidates() -> list[str]:
    chosen = os.environ.get("MUJOCO_GL", "").strip().lower()
    if chosen:
        return [chosen]
    return (["glfw"] if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") else []) + ["egl", "osmesa"]


def mujoco_gl() -> str:
    """The OpenGL backend MuJoCo's renderer uses here (``egl``, ``osmesa`` or ``glfw``), chosen
    by trying each in turn on a tiny context; :class:`RenderError` naming the packages otherwise."""
    if "name" in _GL:
        return str(_GL["name"])
    reasons = []
    for name in _gl_candidates():
        if name in ("egl", "osmesa") and not os.environ.get("PYOPENGL_PLATFORM"):
            os.environ["PYOPENGL_PLATFORM"] = name  # PyOpenGL reads it once, at its first import
        try:
            cls = importlib.import_module(f"mujoco.{name}").GLContext
            ctx = cls(16, 16)
            ctx.make_current()
            ctx.free()
        except Exception as err:  # noqa: BLE001 — a missing library shows up in many ways: the next one
            reasons.append(f"{name}: {type(err).__name__}{': ' + str(err).splitlines()[0] if str(err) else ''}")
            continue
        try:
            from mujoco.rendering.classic import gl_context
        except ImportError:  # MuJoCo before 3.3 kept it at the top
            from mujoco import gl_context
        gl_context.GLContext = cls  # what mujoco.Renderer builds its context from
        _GL["name"] = name
        return name
    raise RenderError("MuJoCo's offscreen renderer has no OpenGL context here (" + "; ".join(reasons)
                      + "): install EGL or OSMesa (apt-get install libegl1 libegl-mesa0 libosmesa6), "
                        "or set MUJOCO_GL")


class _SwimmerFrames:
    """The swimmer drawn by MuJoCo from its state (qpos, qvel) by a fixed camera over the goal."""

    def __init__(self, size=SIZE):
        mujoco_gl()
        import mujoco

        from .sim.mujoco_swimmer import swimmer_xml_path

        self._mj = mujoco
        self.model = mujoco.MjModel.from_xml_path(swimmer_xml_path())
        self.data = mujoco.MjData(self.model)
        try:
            self.renderer = mujoco.Renderer(self.model, height=size[1], width=size[0])
        except Exception as err:  # noqa: BLE001 — the framebuffer may be smaller than asked
            raise RenderError(f"MuJoCo's renderer could not be built ({type(err).__name__}: {err})") from None
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = (0.5, 0.0, 0.0)  # between the start and the spec's goal (x = 0.9)
        cam.distance, cam.elevation, cam.azimuth = 4.5, -60.0, 90.0
        self.camera = cam

    def frame(self, state: np.ndarray, t: int) -> np.ndarray:
        nq = self.model.nq
        self.data.qpos[:] = state[:nq]
        self.data.qvel[:] = state[nq:nq + self.model.nv]
        self._mj.mj_forward(self.model, self.data)
        self.renderer.update_scene(self.data, camera=self.camera)
        return self.renderer.render().copy()

    def close(self) -> None:
        self.renderer.close()


# ---------------------------------------------------------------------------------- state space
class _StateSpaceFrames:
    """Frames of the report's state-space picture: regions and initial box drawn once, the path
    since the episode began and the current state on top."""

    def __init__(self, program, task: Optional[str]):
        from .backends.compare.phase_plots import Example, _panel, scene
        from .backends.compare.plots import pyplot

        t = program.task(task)
        self.name = f"{Path(program.file or 'spec').stem} {t.name}"
        sc = scene(program.system, t.model, program.regions)
        ex = Example(self.name, "policy", sc, policy=[], policy_reach=[])
        self.pairs = sc.projection.pairs
        self.steps = sc.steps
        plt = pyplot()
        n = len(self.pairs)
        self.fig, axes = plt.subplots(1, n, figsize=(PANEL_PX * n / DPI, PANEL_PX / DPI), dpi=DPI, squeeze=False)
        self.axes = list(axes.flat)
        self.lines, self.dots, self.base = [], [], []
        for p, ax in enumerate(self.axes):
            _panel(ax, ex, p)  # the regions, the initial box, axes and limits
            (line,) = ax.plot([], [], color="C0", lw=1.8)
            (dot,) = ax.plot([], [], "o", color="C0", ms=7, mec="k")
            self.lines.append(line)
            self.dots.append(dot)
            self.base.append((ax.get_xlim(), ax.get_ylim()))
        self.title = self.fig.suptitle("", fontsize=11)
        self.fig.tight_layout(rect=(0, 0, 1, 0.93))
        self.path: list[np.ndarray] = []

    def frame(self, state: np.ndarray, t: int) -> np.ndarray:
        if t == 0 or not self.path:
            self.path = []
        self.path.append(np.asarray(state, dtype=np.float64))
        path = np.array(self.path)
        for p, (a, b) in enumerate(self.pairs):
            u = np.arange(len(path), dtype=float) if a is None else path[:, a]
            v = path[:, b]
            self.lines[p].set_data(u, v)
            self.dots[p].set_data(u[-1:], v[-1:])
            (x0, x1), (y0, y1) = self.base[p]
            ok = np.isfinite(u) & np.isfinite(v)
            if ok.any():  # the view grows to keep the path in it, never shrinks within an episode
                x0, x1 = min(x0, u[ok].min()), max(x1, u[ok].max())
                y0, y1 = min(y0, v[ok].min()), max(y1, v[ok].max())
                self.base[p] = ((x0, x1), (y0, y1))
            self.axes[p].set_xlim(x0, x1)
            self.axes[p].set_ylim(y0, y1)
        self.title.set_text(f"{self.name}: step {t}")
        self.fig.canvas.draw()
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        from .backends.compare.plots import pyplot

        pyplot().close(self.fig)


# ---------------------------------------------------------------------------------- the renderer
class Renderer:
    """Frames of one task's states: :meth:`frame` gives an RGB image ``[H, W, 3]`` (uint8) of a
    state at step ``t`` (0 starts a new path); in ``human`` mode :meth:`show` displays it."""

    def __init__(self, program, task: Optional[str] = None, mode: str = "rgb_array"):
        if mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {', '.join(RENDER_MODES)} (or None); got {mode!r}")
        if mode == "human" and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise RenderError("render_mode 'human' needs a display (DISPLAY is not set): use 'rgb_array', "
                              "or asapc eval RUN --video FILE")
        self.mode = mode
        system = program.system
        swimmer = system.kind == "simulator" and getattr(system, "simulator", None) == "mujoco:swimmer"
        self._frames = _SwimmerFrames() if swimmer else _StateSpaceFrames(program, task)
        self.kind = "mujoco" if swimmer else "state space"
        self.fps = float(min(30.0, max(2.0, 1.0 / system.dt))) if system.dt else 10.0
        self._window = None

    def frame(self, state: np.ndarray, t: int) -> np.ndarray:
        return self._frames.frame(np.asarray(state, dtype=np.float64).ravel(), int(t))

    def show(self, state: np.ndarray, t: int) -> None:
        """Draw the frame in a matplotlib window (``human`` mode)."""
        import matplotlib.pyplot as plt

        img = self.frame(state, t)
        if self._window is None:
            if plt.get_backend().lower() == "agg":
                raise RenderError("render_mode 'human' needs an interactive matplotlib backend (such as TkAgg); "
                                  "matplotlib is on Agg here: use 'rgb_array'")
            fig, ax = plt.subplots()
            ax.axis("off")
            self._window = (fig, ax.imshow(img))
        else:
            self._window[1].set_data(img)
        plt.pause(1.0 / self.fps)

    def close(self) -> None:
        self._frames.close()


def make_renderer(program, task: Optional[str] = None, mode: str = "rgb_array") -> Renderer:
    """A :class:`Renderer` for ``task`` of ``program`` (:class:`RenderError` where none can be had)."""
    return Renderer(program, task, mode)


# ---------------------------------------------------------------------------------- video
def write_video(path: Union[str, Path], renderer: Renderer, paths: Sequence[np.ndarray]) -> int:
    """Write the episodes ``paths`` (each ``[steps + 1, n]`` states) one after another as an MP4
    (H.264) at the system's rate, atomically; returns the number of frames.

    :raises RenderError: no video writer (``pip install imageio imageio-ffmpeg``).
    :raises asap_dsl.runs.RunWriteError: the file cannot be written.
    """
    from .runfiles import atomic_path

    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401 — imageio's ffmpeg plugin needs it
    except ImportError:
        raise RenderError("--video needs imageio and imageio-ffmpeg: pip install imageio imageio-ffmpeg") from None
    frames = 0
    # imageio starts ffmpeg with fork + exec, and JAX (loaded by the policy) warns at every fork
    # that a forked child may deadlock: the child execs at once and takes no lock, so it cannot.
    with warnings.catch_warnings(), atomic_path(path) as tmp:
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
        writer = imageio.get_writer(str(tmp), format="FFMPEG", fps=renderer.fps, codec="libx264", quality=7,
                                    pixelformat="yuv420p", macro_block_size=16, ffmpeg_log_level="error")
        try:
            for states in paths:
                for t, s in enumerate(states):
                    if not np.all(np.isfinite(s)):
                        break
                    writer.append_data(renderer.frame(s, t))
                    frames += 1
        finally:
            writer.close()
    return frames


def video_run(run, path: Union[str, Path], *, episodes: int = 1000, seed: Optional[int] = None,
              spec: Union[str, Path, None] = None, examples: int = 3) -> tuple[Path, int, str]:
    """``asapc eval RUN --video FILE``: the run's policy from the first ``examples`` of its
    evaluation states (``episodes`` drawn with ``seed``, default 2024), each episode up to its
    end, as one MP4. Returns the path, the number of frames and the renderer's kind.

    :raises asap_dsl.runs.RunError: the run cannot be read, the path is not an .mp4, or the file
        cannot be written; :class:`RenderError`: no renderer or no video writer (one sentence each).
    """
    from .backends.rl.evaluation import load_run
    from .rollout import Evaluator
    from .runfiles import RunError, shown
    from .runs import RunDir
    from .sampling import EVAL_SEED, task_states

    target = Path(path).expanduser()
    if target.suffix.lower() != ".mp4":
        raise RunError(f"--video writes an MP4 video: give a path ending in .mp4 (not {shown(target)})")
    run_dir = run if isinstance(run, RunDir) else RunDir(run)
    owned = run_dir.lock is None
    run_dir.acquire(exclusive=False)  # nobody retrains the run while its model is read
    try:
        loaded = load_run(run_dir, spec)
        prog, task = loaded.program, loaded.config.task
        states = task_states(prog.system, prog.task(task).model, int(episodes),
                             seed=EVAL_SEED if seed is None else int(seed))[:examples]
        res = Evaluator(prog, task, states).run(loaded.controller(), record=True)
    finally:
        if owned:
            run_dir.release()
    renderer = make_renderer(prog, task)
    try:
        paths = [res.trajectories[i, : int(res.end_step[i]) + 1] for i in range(res.episodes)]
        frames = write_video(target, renderer, paths)
    finally:
        renderer.close()
    return target, frames, renderer.kind
