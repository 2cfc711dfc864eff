"""``asapc export``: the exported ONNX and TorchScript files, run with onnxruntime and
``torch.jit.load`` on 1000 states, give the project's controller's actions (observation and
action scaling folded in) for SAC and PPO on both engines, TD3 on a task that observes time; the
metadata names the run, the states and the actions; bad input is one sentence."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from asap_dsl import cli
from asap_dsl.runs import RunDir
from asap_dsl.sampling import EVAL_SEED, task_states
from conftest import ROOT, asapc, one_line_error

ort = pytest.importorskip("onnxruntime")
torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

HEAD = "task reach {\n  asap       in goal\n  deadline   30\n  tolerances 30, 25, 15\n"
# Gradient steps within 300 environment steps (as tests/test_engines.py trains).
BLOCK = {"off": "train { learning_starts = 64, batch_size = 32 }", "on": "train { n_steps = 32, batch_size = 32 }"}
# (engine, algo, preset, observe time): the default preset scales observations and actions, the
# paper preset neither; TD3 on a task observing time covers the step input.
RUNS = [("sb3", "sac", "default", False), ("sbx", "sac", "default", False), ("sb3", "ppo", "paper", False),
        ("sbx", "ppo", "default", False), ("sb3", "td3", "default", True)]


def _spec(tmp: Path, algo: str, observe_time: bool) -> Path:
    src = (ROOT / "specs" / "dc_motor.asap").read_text()
    kind = "on" if algo in ("ppo", "a2c") else "off"
    extra = f"  {BLOCK[kind]}\n" + ("  observe    state, time\n" if observe_time else "")
    assert HEAD in src
    p = tmp / f"dc_{kind}{'_t' if observe_time else ''}.asap"
    p.write_text(src.replace(HEAD, HEAD + extra))
    return p


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict:
    """A tiny run of each of RUNS (300 steps on DC motor's reach)."""
    tmp = tmp_path_factory.mktemp("export")
    out = {}
    for engine, algo, preset, timed in RUNS:
        run = tmp / f"{engine}-{algo}-{preset}{'-t' if timed else ''}"
        code = cli.main(["train", str(_spec(tmp, algo, timed)), "--task", "reach", "--algo", algo, "--engine", engine,
                         "--preset", preset, "--steps", "300", "--envs", "2", "--demonstrations", "0",
                         "--out", str(run), "--quiet", "--no-eval"])
        assert code == 0, (engine, algo)
        out[(engine, algo, preset, timed)] = run
    return out


def _states(prog, task: str) -> tuple[np.ndarray, np.ndarray]:
    """The 1000 evaluation states, and 1000 drawn over the state space and a tenth beyond it
    (where the observation is clipped, and the scaled inputs lie far outside the training box)."""
    sysm = prog.system
    evaluation = task_states(sysm, prog.task(task).model, 1000, seed=EVAL_SEED)
    width = sysm.state_high - sysm.state_low
    wide = np.random.default_rng(5).uniform(sysm.state_low - 0.1 * width, sysm.state_high + 0.1 * width,
                                            size=(1000, sysm.n_state))
    return evaluation, wide


def _controller_actions(loaded, states: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """What the project's controller does with these raw states at these steps of an evaluation
    episode (it lasts the deadline): the environment's observation, then PolicyController.act."""
    from asap_dsl.env import EnvCore

    prog, task = loaded.program, loaded.config.task
    core = EnvCore(prog, task, len(states), None, autoreset=False)
    deadline = prog.task(task).model.deadline
    obs = core.obs(states, t=steps, k=np.full(len(states), deadline))
    return loaded.controller().act(obs, states, 0)


@pytest.mark.parametrize("key", RUNS, ids=["-".join(map(str, k[:3])) + ("-time" if k[3] else "") for k in RUNS])
def test_exported_files_give_the_controllers_actions(runs, key, tmp_path, capsys):
    _check_export(runs[key], key, tmp_path, capsys)


def test_a_kept_models_action_gain_is_in_the_exported_files(runs, tmp_path, capsys):
    """A model the policy search kept acts with its gain (``best.action_gain``): the controller,
    the ONNX and the TorchScript file alike, and more of its actions sit on the bounds."""
    import shutil

    from asap_dsl.backends.rl.evaluation import load_run

    key = ("sbx", "sac", "default", False)
    run = tmp_path / "gained"
    shutil.copytree(runs[key], run)
    with RunDir(run) as rd:
        rd.acquire(exclusive=True)
        best = rd.read_manifest()["best"]
        rd.update_manifest(best={**best, "action_gain": 25.0})
    plain, gained = load_run(runs[key]), load_run(run)
    assert gained.scaling.gain == 25.0 and plain.scaling.gain == 1.0
    states = _states(plain.program, "reach")[0]
    zero = np.zeros(len(states), dtype=np.int64)
    a1, a15 = _controller_actions(plain, states, zero), _controller_actions(gained, states, zero)
    np.testing.assert_allclose(np.clip(25.0 * a1, -20.0, 20.0), a15, atol=1e-9)  # V in [-20, 20], centred
    assert (np.abs(a15) == 20.0).sum() > (np.abs(a1) == 20.0).sum() + 100
    meta = _check_export(run, key, tmp_path, capsys)
    assert meta["action_gain"] == 25.0
    from asap_dsl.runs import RunError

    for bad in (0.5, "1.5", float("nan")):  # a manifest edited by hand: one sentence
        with RunDir(run) as rd:
            rd.acquire(exclusive=True)
            rd.update_manifest(best={**best, "action_gain": bad})
        with pytest.raises(RunError, match="damaged manifest"):
            load_run(run)


def _check_export(run: Path, key: tuple, tmp_path: Path, capsys) -> dict:
    """The run's exported ONNX and TorchScript files against its controller; their metadata."""
    from asap_dsl.backends.rl.evaluation import load_run
    from asap_dsl.backends.rl.export import read_metadata

    engine, algo, preset, timed = key
    onnx_file, ts_file = tmp_path / "p.onnx", tmp_path / "p.pt"
    for fmt, path in (("onnx", onnx_file), ("torchscript", ts_file)):
        code, text, err = asapc(capsys, "export", run, "--format", fmt, "--out", path)
        assert code == 0, err
        assert str(path) in text and f"{algo} on {engine}" in text
    loaded = load_run(run)
    manifest = RunDir(run).read_manifest()
    sess = ort.InferenceSession(str(onnx_file))
    module = torch.jit.load(str(ts_file))
    assert [i.name for i in sess.get_inputs()] == (["state", "step"] if timed else ["state"])
    half = (loaded.program.system.action_high - loaded.program.system.action_low) / 2
    rng = np.random.default_rng(11)
    for which, states in zip(("evaluation", "wide"), _states(loaded.program, "reach")):
        steps = rng.integers(0, 35, size=len(states)) if timed else np.zeros(len(states), dtype=np.int64)
        want = _controller_actions(loaded, states, steps)
        feeds = {"state": states.astype(np.float32)}
        args = [torch.as_tensor(states, dtype=torch.float32)]
        if timed:
            feeds["step"] = steps.astype(np.float32)
            args.append(torch.as_tensor(steps, dtype=torch.float32))
        got_onnx = sess.run(["action"], feeds)[0]
        got_ts = module(*args).numpy()
        assert got_onnx.shape == got_ts.shape == want.shape == (1000, 1)
        for got in (got_onnx, got_ts):
            err = np.abs(got - want)
            # On the evaluation states, 1e-5 in the action's units (volts); across the state space,
            # 1e-5 of the action's half-range: two float32 networks (torch or XLA against MLAS)
            # differ there by a few units in the last place of tanh near saturation, times 20 V.
            # A gain multiplies the networks' difference as it does the action.
            bound = (1e-5 if which == "evaluation" else 1e-5 * half) * loaded.scaling.gain
            assert (err <= bound).all(), (which, float(err.max()))
        assert np.ptp(want) > 0  # the policy is not constant: the comparison says something
    for path in (onnx_file, ts_file):
        meta = read_metadata(path)
        assert meta["model_sha256"] == manifest["model"]["sha256"] and meta["spec_hash"] == manifest["spec_hash"]
        assert meta["state_names"] == ["theta", "omega", "i"] and meta["action_names"] == ["V"]
        assert meta["action_low"] == [-20.0] and meta["action_high"] == [20.0]
        assert (meta["algo"], meta["engine"], meta["observe_time"]) == (algo, engine, timed)
    return meta


def test_the_default_file_is_in_the_run_and_the_torchscript_metadata_is_json(runs, capsys):
    run = runs[("sb3", "sac", "default", False)]
    code, text, err = asapc(capsys, "export", run, "--format", "torchscript")
    assert code == 0, err
    extra = {"asap.json": ""}
    module = torch.jit.load(str(run / "policy.pt"), _extra_files=extra)
    assert json.loads(extra["asap.json"])["inputs"] == ["state"]
    a = module(torch.zeros((2, 3))).numpy()
    assert a.shape == (2, 1) and np.all(np.abs(a) <= 20)
    code, text, err = asapc(capsys, "export", run)
    assert code == 0 and (run / "policy.onnx").is_file(), err
    sess = ort.InferenceSession((run / "policy.onnx").read_bytes())
    assert sess.run(None, {"state": np.zeros((1, 3), np.float32)})[0].shape == (1, 1)


def test_bad_run_path_or_format_is_one_sentence(runs, tmp_path, capsys):
    code, _, err = asapc(capsys, "export", tmp_path / "nowhere")
    assert code == 1 and "no such run directory" in one_line_error(err)
    (tmp_path / "empty").mkdir()
    code, _, err = asapc(capsys, "export", tmp_path / "empty")
    assert code == 1 and one_line_error(err)
    run = runs[("sb3", "ppo", "paper", False)]
    code, _, err = asapc(capsys, "export", run, "--format", "tflite")
    assert code == 2 and "invalid choice: 'tflite'" in err.strip().splitlines()[-1] and "Traceback" not in err
    blocker = tmp_path / "file"
    blocker.write_text("")
    code, _, err = asapc(capsys, "export", run, "--out", blocker / "p.onnx")
    assert code == 1 and "cannot write" in one_line_error(err)


def test_export_never_replaces_a_runs_own_file_or_a_device_and_a_refused_name_is_one_sentence(runs, tmp_path, capsys):
    run = runs[("sb3", "ppo", "paper", False)]
    manifest = (run / "run.json").read_bytes()
    code, _, err = asapc(capsys, "export", run, "--out", run / "run.json")
    assert code == 1 and "one of the run's own files" in one_line_error(err)
    assert (run / "run.json").read_bytes() == manifest  # the run is intact
    code, _, err = asapc(capsys, "export", run, "--out", "/dev/null")
    assert code == 1 and "not a regular file" in one_line_error(err)
    # a name the system refuses (too long for the file system) is the user's, not an internal error
    code, _, err = asapc(capsys, "export", run, "--out", tmp_path / ("a" * 300 + ".onnx"))
    assert code == 1 and "name too long" in one_line_error(err) and "internal error" not in err
    # a manifest nested too deep for Python's decoder is a damaged file, said in one sentence
    import shutil

    copy = tmp_path / "deep"
    shutil.copytree(run, copy)
    (copy / "run.json").write_text("[" * 100_000 + "]" * 100_000)
    code, _, err = asapc(capsys, "export", copy, "--out", tmp_path / "p.onnx")
    assert code == 1 and "unreadable manifest" in one_line_error(err) and "internal error" not in err
