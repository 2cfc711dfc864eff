"""Watching a task: ``render_mode="rgb_array"`` frames (MuJoCo's offscreen renderer for the
swimmer, a state-space frame for ODE systems), ``"human"`` refused without a display, and
``asapc eval RUN --video FILE``'s MP4 decoded frame by frame."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import asap_dsl
from asap_dsl.env import make_env
from asap_dsl.render import RenderError, make_renderer, write_video
from asap_dsl.rollout import Evaluator
from conftest import ROOT, asapc, one_line_error

SWIMMER = ROOT / "specs" / "swimmer.asap"
DC_MOTOR = ROOT / "specs" / "dc_motor.asap"


def _decoded(path) -> list[tuple[float, float]]:
    """Per frame of an MP4: its pixels' std and its mean absolute change from the frame before."""
    iio = pytest.importorskip("imageio.v2")
    out, prev = [], None
    for frame in iio.get_reader(str(path)):
        f = frame.astype(np.int16)
        out.append((float(f.std()), 0.0 if prev is None else float(np.abs(f - prev).mean())))
        prev = f
    return out


def _mujoco_or_skip(prog):
    try:
        return make_renderer(prog, "reach")
    except RenderError as err:
        if os.environ.get("CI"):
            pytest.fail(f"CI must have EGL or OSMesa (see scripts/setup): {err}")
        pytest.skip(str(err))


class _Strokes:
    """Opposite sine torques on the two joints: the swimmer's body visibly undulates."""

    def reset(self, states):
        pass

    def act(self, obs, states, t):
        phase = 0.6 * t
        return np.tile([np.sin(phase), -np.sin(phase + 1.0)], (len(states), 1))


def test_swimmer_video_decodes_to_every_state_of_its_episodes(tmp_path):
    prog = asap_dsl.load(SWIMMER)
    renderer = _mujoco_or_skip(prog)
    states = np.zeros((2, 10))
    states[1, 0] = 0.3
    res = Evaluator(prog, "reach", states, steps=12).run(_Strokes(), record=True)
    paths = [res.trajectories[i, : int(res.end_step[i]) + 1] for i in range(2)]
    out = tmp_path / "swimmer.mp4"
    try:
        frames = write_video(out, renderer, paths)
    finally:
        renderer.close()
    assert renderer.kind == "mujoco" and renderer.fps == 25.0  # dt 0.04
    assert frames == 26 and out.stat().st_size > 10_000
    decoded = _decoded(out)
    assert len(decoded) == 26
    assert min(s for s, _ in decoded) > 20  # a picture (the floor's checks, the body), not a flat colour
    assert np.mean([d for _, d in decoded[1:]]) > 0.05  # and it moves


def test_rgb_array_frames_and_human_without_a_display(monkeypatch):
    env = make_env(DC_MOTOR, "reach", render_mode="rgb_array", seed=1)
    env.reset()
    first = env.render()
    for _ in range(4):
        env.step(np.array([20.0]))
    later = env.render()
    env.close()
    assert first.shape == later.shape == (480, 480, 3) and first.dtype == np.uint8
    assert first.std() > 5 and np.abs(later.astype(int) - first).sum() > 0  # the path grew
    assert env.metadata["render_fps"] == 10.0
    assert make_env(DC_MOTOR, "reach").render() is None  # no render mode: gymnasium's None
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(RenderError, match="needs a display"):
        make_env(DC_MOTOR, "reach", render_mode="human")
    with pytest.raises(ValueError, match="render_mode must be one of rgb_array, human"):
        make_env(DC_MOTOR, "reach", render_mode="ansi")
    prog = asap_dsl.load(SWIMMER)
    renderer = _mujoco_or_skip(prog)
    env = make_env(prog, "reach", render_mode="rgb_array", seed=0)
    env.reset()
    img = env.render()
    env.close()
    renderer.close()
    assert img.shape == (480, 640, 3) and img.std() > 20


def test_eval_video_of_an_ode_system_and_a_bad_path(tiny, tmp_path, capsys):
    from asap_dsl.backends.rl.evaluation import load_run
    from asap_dsl.sampling import EVAL_SEED, task_states

    run = tmp_path / "run"
    code, _, err = asapc(capsys, "train", tiny, "--algo", "sac", "--engine", "sb3", "--steps", 300, "--envs", 2,
                         "--out", run, "--quiet", "--no-eval")
    assert code == 0, err
    video = tmp_path / "rail.mp4"
    code, text, err = asapc(capsys, "eval", run, "--no-oracle", "--episodes", 40, "--format", "json", "--video", video)
    assert code == 0, err
    info = json.loads(text)["video"]
    loaded = load_run(run)
    prog = loaded.program
    states = task_states(prog.system, prog.task("go").model, 40, seed=EVAL_SEED)[:3]
    res = Evaluator(prog, "go", states).run(loaded.controller())
    expected = int((res.end_step + 1).sum())
    assert info["frames"] == expected and info["renderer"] == "state space"
    decoded = _decoded(video)
    assert len(decoded) == expected
    assert min(s for s, _ in decoded) > 5
    assert max(d for _, d in decoded) > 0  # the path is drawn as it goes
    code, text, err = asapc(capsys, "eval", run, "--no-oracle", "--episodes", 40, "--video", tmp_path / "rail.avi")
    line = one_line_error(err)
    assert code == 1 and "ending in .mp4" in line and "no video was written" in line
    assert "success" in text  # the evaluation was shown first
