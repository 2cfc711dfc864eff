"""Run directories against other processes and the operating system (issue 19), each fault as
it happens: a second process on a run, kill -9 of compare and of train at random moments, two and
three Ctrl-C, SIGTERM after the sweep, a full disk (a small tmpfs), a read-only run, and Ray as a
real cluster whose worker node is killed mid-sweep.

Every process a test starts carries ``ASAP_TEST_TAG`` in its environment, so that what is left
behind after a kill (a worker that outlived its parent) is found by scanning /proc."""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import pytest

from asap_dsl import cli
from asap_dsl.runfiles import holder
from asap_dsl.runs import RunDir
from conftest import RAIL

IS_LINUX = sys.platform.startswith("linux")
pytestmark = pytest.mark.skipif(not IS_LINUX, reason="/proc, flock holders and prctl as on Linux")
ROOT = Path(__file__).resolve().parent.parent


class Proc:
    """``asapc ARGS`` in a process of its own, its output collected as it comes."""

    def __init__(self, *args, tag: str, env: dict | None = None):
        self.tag = tag
        full = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1", ASAP_TEST_TAG=tag, **(env or {}))
        self.p = subprocess.Popen([sys.executable, "-m", "asap_dsl.cli", *map(str, args)], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, env=full, cwd=ROOT,
                                  preexec_fn=_as_from_a_terminal)
        self.pid = self.p.pid
        self.out: list[str] = []
        self.err: list[str] = []
        self._readers = [threading.Thread(target=self._read, args=(s, b), daemon=True)
                         for s, b in ((self.p.stdout, self.out), (self.p.stderr, self.err))]
        for t in self._readers:
            t.start()

    @staticmethod
    def _read(stream, into) -> None:
        for line in stream:
            into.append(line)

    @property
    def stderr(self) -> str:
        return "".join(self.err)

    def wait_for(self, text: str, timeout: float = 240) -> bool:
        end = time.time() + timeout
        while time.time() < end:
            if any(text in line for line in self.err) or any(text in line for line in self.out):
                return True
            if self.p.poll() is not None:
                time.sleep(0.2)
                return any(text in line for line in self.err + self.out)
            time.sleep(0.05)
        return False

    def signal(self, sig: int) -> None:
        if self.p.poll() is None:
            os.kill(self.pid, sig)

    def finish(self, timeout: float = 600) -> int:
        code = self.p.wait(timeout)
        for t in self._readers:
            t.join(10)
        return code


def _as_from_a_terminal() -> None:
    # A test runner may start us with SIGINT ignored, and asapc keeps an ignored SIGINT ignored
    # (as a background job's). A terminal's Ctrl-C finds the default.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def tagged(tag: str) -> list[int]:
    """Processes whose environment carries the tag (what a test started, and their children)."""
    needle = f"ASAP_TEST_TAG={tag}\0".encode()
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if needle in (d / "environ").read_bytes():
                    out.append(int(d.name))
            except OSError:
                pass
    return out


def gone(tag: str, timeout: float = 20) -> list[int]:
    """Wait for every tagged process to end; those left (and their command lines) otherwise."""
    end = time.time() + timeout
    while time.time() < end:
        left = [p for p in tagged(tag) if not _zombie(p)]
        if not left:
            return []
        time.sleep(0.2)
    return left


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] == "Z"
    except OSError:
        return True


def _clean(text: str) -> None:
    assert "Traceback" not in text, text
    assert "internal error" not in text, text


def _cli(capsys, *argv):
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as e:
        code = e.code
    return code, capsys.readouterr().err


@pytest.fixture()
def spec(tmp_path):
    p = tmp_path / "rail.asap"
    p.write_text(RAIL)
    return p


@pytest.fixture()
def tag():
    t = uuid.uuid4().hex
    yield t
    for pid in tagged(t):  # whatever a failed test left running
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


TRAIN = ["--envs", "2", "--engine", "sb3", "--no-eval"]


# -------------------------------------------------------------------------------- 2. one owner
def test_a_run_has_one_owner(spec, tmp_path, tag, capsys):
    run = tmp_path / "D"
    a = Proc("train", spec, "--steps", 1_000_000, "--out", run, *TRAIN, tag=tag)
    assert a.wait_for("training:"), a.stderr
    for argv in (["train", spec, "--steps", 800, "--seed", 5, "--out", run, "--force", *TRAIN],
                 ["train", spec, "--out", run, "--resume", *TRAIN],
                 ["eval", run, "--no-oracle"]):
        code, err = _cli(capsys, *argv)
        assert code == 1 and f"is in use by process {a.pid} (asapc train" in err, (argv, err)
        _clean(err)
    a.signal(signal.SIGTERM)
    assert a.finish() == 130, a.stderr
    stopped = RunDir(run).read_manifest()
    assert stopped["config"]["seed"] == 0 and stopped["status"] == "interrupted"
    # two --resume at once: one trains, the other is refused naming it
    b = Proc("train", spec, "--out", run, "--resume", *TRAIN, tag=tag)
    c = Proc("train", spec, "--out", run, "--resume", *TRAIN, tag=tag)
    end = time.time() + 240
    while time.time() < end and b.p.poll() is None and c.p.poll() is None:
        time.sleep(0.1)
    loser, winner = (b, c) if b.p.poll() is not None else (c, b)
    assert loser.finish() == 1 and f"in use by process {winner.pid}" in loser.stderr, loser.stderr
    assert winner.wait_for("training:"), winner.stderr
    winner.signal(signal.SIGTERM)
    assert winner.finish() == 130
    m = RunDir(run).read_manifest()
    assert m["steps_done"] >= stopped["steps_done"] and RunDir(run).checkpoint().steps == m["steps_done"]
    assert gone(tag) == []


# -------------------------------------------------------------------------------- 5. Ctrl-C
def test_two_and_three_ctrl_c(spec, tmp_path, tag):
    runs = {n: tmp_path / f"c{n}" for n in (2, 3)}
    procs = {n: Proc("train", spec, "--steps", 1_000_000, "--out", runs[n], *TRAIN, tag=tag) for n in runs}
    for n, p in procs.items():
        assert p.wait_for("training:"), p.stderr
    time.sleep(1.0)
    for k in range(3):  # 2: Ctrl-C, 50 ms, Ctrl-C; 3: three, 20 ms apart
        for n, p in procs.items():
            if k < n:
                p.signal(signal.SIGINT)
        time.sleep(0.05 if k == 0 else 0.02)
    two = procs[2]
    assert two.finish() == 130
    _clean(two.stderr)
    assert "continue with `asapc train" in two.stderr
    m = RunDir(runs[2]).read_manifest()
    assert m["status"] == "interrupted" and m["steps_done"] > 0
    assert RunDir(runs[2]).checkpoint().steps == m["steps_done"]  # the checkpoint was waited for
    three = procs[3]
    assert three.finish() == 130
    _clean(three.stderr)
    assert "aborted" in three.stderr or "continue with" in three.stderr
    m3 = RunDir(runs[3]).read_manifest()  # aborted or not, the run can resume from a checkpoint
    assert m3["status"] == "interrupted" and RunDir(runs[3]).checkpoint() is not None
    r = Proc("train", spec, "--out", runs[2], "--resume", "--steps", m["steps_done"] + 40, *TRAIN, tag=tag)
    assert r.finish() == 0, r.stderr
    assert RunDir(runs[2]).read_manifest()["steps_done"] >= m["steps_done"] + 40
    assert gone(tag) == []


# -------------------------------------------------------------------------------- 3, 4. compare
def test_kill_9_of_compare_leaves_no_process_and_the_rerun_resumes(spec, tmp_path, tag, capsys):
    out = tmp_path / "O"
    cmd = ["compare", spec, "--rewards", "asap,rho", "--seeds", 1, "--steps", 1500, "--episodes", 30,
           "--workers", 2, "--out", out]
    env = {"ASAP_CHECKPOINT_SECONDS": "1"}
    p = Proc(*cmd, tag=tag, env=env)
    end, workers = time.time() + 300, set()
    while time.time() < end and len(workers) < 2 and p.p.poll() is None:
        dirs = list((out / "runs").glob("rail-*")) if (out / "runs").is_dir() else []
        workers = {h for h in (holder(d) for d in dirs) if h is not None}
        time.sleep(0.2)
    assert len(workers) == 2, p.stderr
    # 4: a second compare on the same --out is refused, naming the first
    code, err = _cli(capsys, *cmd)
    assert code == 1 and f"is in use by process {p.pid}" in err, err
    _clean(err)
    time.sleep(1.5)  # a periodic checkpoint or two
    before = {d.name: RunDir(d).read_manifest() for d in (out / "runs").glob("rail-*")}
    os.kill(p.pid, signal.SIGKILL)
    p.finish()
    assert gone(tag) == [], "workers outlived compare"
    again = Proc(*cmd, tag=tag, env=env)
    assert again.finish() == 0, again.stderr
    _clean(again.stderr)
    after = {d.name: RunDir(d).read_manifest() for d in (out / "runs").glob("rail-*")}
    assert set(after) == set(before)
    for name, m in after.items():  # resumed from their checkpoints, not started over
        assert m["status"] == "finished" and m["created"] == before[name]["created"]
        assert m["steps_done"] >= 1500 or "plateau_step" in m  # all its steps, or ended on its plateau (conftest.completed)
    # SIGTERM once the sweep is done (the oracle, the evaluations, the report): 130, saying when
    last = Proc(*cmd, tag=tag)
    assert last.wait_for("[2/2]"), last.stderr
    last.signal(signal.SIGTERM)
    code = last.finish()
    _clean(last.stderr)
    assert code == 130 and "interrupted during" in last.stderr or code == 0, last.stderr
    assert gone(tag) == []


def test_kill_9_of_the_oracle_leaves_no_worker(spec, tmp_path, tag):
    """A worker used to finish its chunk of states (here 1,250, a minute or so) after `asapc oracle`
    was killed, and only then found nobody to give them to. It dies with the oracle now (the
    planner's pool starts its workers alike)."""
    p = Proc("oracle", spec, "--episodes", 20000, "--workers", 2, tag=tag)
    end = time.time() + 240
    while time.time() < end and len(tagged(tag)) < 3 and p.p.poll() is None:
        time.sleep(0.2)
    assert len(tagged(tag)) >= 3, p.stderr  # asapc and its two workers
    time.sleep(1)  # into their first chunks
    os.kill(p.pid, signal.SIGKILL)
    p.finish()
    assert gone(tag, timeout=10) == [], "the oracle's workers outlived it"


# -------------------------------------------------------------------------------- 7. full disk
@pytest.fixture()
def small_disk(tmp_path):
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a small tmpfs needs root")
    mnt = tmp_path / "disk"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_a_full_disk_stops_the_run_with_its_checkpoint_intact(spec, small_disk, tag):
    run = small_disk / "run"
    p = Proc("train", spec, "--steps", 20_000, "--out", run, *TRAIN, tag=tag, env={"ASAP_CHECKPOINT_SECONDS": "0.5"})
    assert p.finish() == 1, p.stderr
    _clean(p.stderr)
    line = p.stderr.strip().splitlines()[-1]
    assert line.startswith("asapc: error: cannot write ") and "no space left on device" in line, line
    assert "is intact; free some space, then continue with `asapc train" in line
    m = RunDir(run).read_manifest()
    assert m["status"] == "failed" and "no space left" in m["error"]
    assert not (run / "checkpoint.new").exists() and not list(run.glob(".*.tmp*"))
    subprocess.run(["mount", "-o", "remount,size=64m", str(small_disk)], check=True)
    r = Proc("train", spec, "--out", run, "--resume", "--steps", m["steps_done"] + 40, *TRAIN, tag=tag)
    assert r.finish() == 0, r.stderr
    assert RunDir(run).read_manifest()["status"] == "finished"


def test_eval_of_a_read_only_run_prints_and_says_it_could_not_store(spec, tmp_path, tag, capsys):
    if os.geteuid() != 0:
        pytest.skip("a read-only bind mount needs root (root writes through permissions)")
    import asap_dsl

    run = tmp_path / "ro"
    asap_dsl.train(spec, steps=100, n_envs=2, out=run, engine="sb3", evaluate=False,
                   settings={"net_arch": [16, 16], "learning_starts": 64, "batch_size": 32}, eval_episodes=20)
    if subprocess.run(["mount", "--bind", str(run), str(run)], capture_output=True).returncode != 0:
        pytest.skip("cannot bind-mount here")
    try:
        if subprocess.run(["mount", "-o", "remount,ro,bind", str(run)], capture_output=True).returncode != 0:
            pytest.skip("cannot remount read-only here")
        try:
            code = cli.main(["eval", str(run), "--no-oracle", "--episodes", "20"])  # the run's own: stored
        except SystemExit as e:
            code = e.code
        out, err = capsys.readouterr()
        assert code == 1 and "within" in out, (out, err)
        assert "eval.json: read-only file system (the evaluation above was not stored)" in err, err
        _clean(err)
    finally:
        subprocess.run(["umount", "-l", str(run)], capture_output=True)


# -------------------------------------------------------------------------------- random faults
def test_a_signal_after_the_command_has_finished_does_not_change_its_status(spec, tmp_path, tag):
    """SIGTERM while the finished program tears torch down: exit 0 or 130, never killed (-15). The
    window is a few hundred milliseconds after the last line (Python resets its handlers to the
    default there); the random schedule below found it on CI."""
    for i, delay in enumerate((0.05, 0.1, 0.2)):
        p = Proc("train", spec, "--out", tmp_path / f"R{i}", "--steps", 300, *TRAIN, tag=tag)
        assert p.wait_for("times,"), p.stderr  # the run's last line: "validation: 3 times, ..."
        time.sleep(delay)
        p.signal(signal.SIGTERM)
        code = p.finish()
        assert code in (0, 130), (delay, code, p.stderr[-600:])
        _clean(p.stderr)
    assert gone(tag) == []


def test_sigterm_inside_a_string_run_by_exec_still_exits_130(spec, tmp_path, tag):
    """The random schedule's other finding: SIGTERM while an import ran a string through ``exec``
    (a dataclass being built) made ``python -m asap_dsl.cli`` end by SIGINT (-2) after it had
    printed "interrupted". Here the signal lands inside such a string every time."""
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(
        "import argparse, os, signal\n"
        "_parse = argparse.ArgumentParser.parse_args\n"
        "def parse_args(self, *a, **k):\n"
        "    if self.prog == 'asapc':\n"
        "        exec('os.kill(os.getpid(), signal.SIGTERM)\\nfor _ in range(10**7): pass', "
        "{'os': os, 'signal': signal})\n"
        "    return _parse(self, *a, **k)\n"
        "argparse.ArgumentParser.parse_args = parse_args\n")
    p = Proc("lint", spec, tag=tag, env={"PYTHONPATH": f"{hook}{os.pathsep}{ROOT}"})
    code = p.finish()
    assert code == 130 and p.stderr == "interrupted\n", (code, p.stderr)


def test_random_fault_schedule(spec, tmp_path, tag):
    """kill -9 (or SIGTERM) at a random moment, then resume or rerun, again and again; after
    each: only exit 0/1/2/130, no traceback, the run finished or resumable from a checkpoint that
    never goes back, nothing left running. The seed is printed when it fails."""
    seed = int(os.environ.get("ASAP_FAULT_SEED", random.randrange(1 << 30)))
    rng = random.Random(seed)
    run = tmp_path / "R"
    steps = 1200
    last = -1
    env = {"ASAP_CHECKPOINT_SECONDS": "0.3"}
    for i in range(6):
        final = i == 5
        cmd = (["train", spec, "--out", run, "--resume"] if RunDir(run).exists() else
               ["train", spec, "--out", run, "--steps", steps]) + TRAIN
        p = Proc(*cmd, tag=tag, env=env)
        how = "none" if final else rng.choice(["kill", "kill", "term"])
        if how != "none":
            time.sleep(rng.uniform(0.5, 7.0))
            p.signal(signal.SIGKILL if how == "kill" else signal.SIGTERM)
        code = p.finish()
        where = f"(seed {seed}, round {i}, {how}: {p.stderr[-600:]})"
        if code != -signal.SIGKILL:
            assert code in (0, 1, 2, 130), where
            _clean(p.stderr)
        assert gone(tag) == [], where
        if not RunDir(run).exists():
            assert last < 0, where  # only a kill before the run existed leaves nothing
            continue
        r = RunDir(run)
        m = r.read_manifest()
        ckpt = r.checkpoint(m)
        assert ckpt is not None and m["status"] in ("running", "interrupted", "finished"), where
        assert ckpt.steps >= last, where  # never back past the last checkpoint
        last = ckpt.steps
        if m["status"] == "finished":
            break
    assert RunDir(run).read_manifest()["status"] == "finished" and last >= steps
    assert not list(tmp_path.glob(".R.new-*"))  # stages of killed creations are cleaned up


# -------------------------------------------------------------------------------- 9. Ray
def test_ray_addresses_that_cannot_be_used_are_one_sentence(spec, tmp_path, capsys):
    pytest.importorskip("ray")
    base = ["compare", spec, "--rewards", "asap", "--seeds", 1, "--steps", 100, "--episodes", 10, "--out", tmp_path / "o"]
    for address in ("not an address", "256.1.1.1:99999", "host:", ":80"):
        code, err = _cli(capsys, *base, "--ray", address)
        assert code == 2 and "is not a Ray address" in err, (address, err)
    t = time.time()
    code, err = _cli(capsys, *base, "--ray", "127.0.0.1:1", "--ray-timeout", 3)
    assert code == 1 and "cannot reach a Ray cluster at 127.0.0.1:1 within 3 s" in err, err
    # unroutable: refused at connect, or accepted by a middlebox and never answered (then Ray's retries
    # keep fd 2 and the sentence goes to the real stderr): in a process of its own to see that stderr
    p = Proc(*base, "--ray", "10.255.255.1:6379", "--ray-timeout", 2, tag="ray-unroutable")
    code, err = p.finish(timeout=60), p.stderr
    assert code == 1 and "Ray cluster at 10.255.255.1:6379" in err and "within 2 s" in err, err
    assert time.time() - t < 30
    _clean(err)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Node:
    """``ray start ... --block`` in a session of its own: killing its process group kills the node."""

    def __init__(self, args: list[str], env: dict):
        self.p = subprocess.Popen([str(Path(sys.executable).parent / "ray"), "start", *args, "--block",
                                   "--disable-usage-stats"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  text=True, env=env, start_new_session=True)
        self.lines: list[str] = []
        threading.Thread(target=lambda: [self.lines.append(x) for x in self.p.stdout], daemon=True).start()

    def started(self, timeout: float = 120) -> bool:
        end = time.time() + timeout
        while time.time() < end and self.p.poll() is None:
            if any("Ray runtime started" in x for x in self.lines):
                return True
            time.sleep(0.2)
        return False

    def kill(self, sig: int = signal.SIGKILL) -> None:
        try:
            os.killpg(self.p.pid, sig)
        except OSError:
            pass


def test_ray_cluster_with_a_worker_node_killed_mid_sweep(spec, tmp_path, tag):
    """A head and a worker node started with `ray start` (token authentication on, as Ray sets it
    up); compare --ray runs on them; the worker node is killed while its run trains; the run is
    retried on the head and the report is the one a local sweep writes."""
    pytest.importorskip("ray")
    temp = Path(os.path.realpath(__import__("tempfile").mkdtemp(prefix="ray", dir="/tmp")))  # sockets: short paths
    token = tmp_path / "token"
    token.write_text(uuid.uuid4().hex + uuid.uuid4().hex)
    port = _free_port()
    # The cluster's token in a file of its own (not ~/.ray/auth_token); a node given it that way is
    # told the mode (a head turns it on by itself; a node joining with the default file too).
    env = dict(os.environ, ASAP_TEST_TAG=tag, OMP_NUM_THREADS="1", RAY_AUTH_TOKEN_PATH=str(token), RAY_AUTH_MODE="token",
               # a dead node is noticed in seconds, not the default half minute
               RAY_health_check_period_ms="500", RAY_health_check_timeout_ms="1000",
               RAY_health_check_failure_threshold="3", RAY_health_check_initial_delay_ms="1000")
    head = _Node(["--head", "--port", str(port), "--num-cpus", "1", "--temp-dir", str(temp), "--include-dashboard",
                  "false", "--ray-client-server-port", str(_free_port())], env)
    nodes = [head]
    try:
        assert head.started(), "".join(head.lines)
        worker = _Node(["--address", f"127.0.0.1:{port}", "--num-cpus", "1"], env)
        nodes.append(worker)
        assert worker.started(), "".join(worker.lines)
        common = ["--rewards", "asap,rho", "--seeds", 1, "--steps", 1200, "--episodes", 30]
        local = Proc("compare", spec, *common, "--workers", 1, "--out", tmp_path / "local", tag=tag)
        remote = Proc("compare", spec, *common, "--out", tmp_path / "ray", "--ray", f"127.0.0.1:{port}", tag=tag,
                      env={"RAY_AUTH_TOKEN_PATH": str(token)})
        end, victim = time.time() + 300, None
        while time.time() < end and victim is None and remote.p.poll() is None:
            for d in (tmp_path / "ray" / "runs").glob("rail-*") if (tmp_path / "ray" / "runs").is_dir() else []:
                h = holder(d)
                if h is not None and _on_node(h, worker.p.pid):
                    victim = h
            time.sleep(0.2)
        assert victim is not None, remote.stderr
        time.sleep(1.0)
        worker.kill()
        assert remote.finish(900) == 0, remote.stderr
        assert local.finish(900) == 0, local.stderr
        _clean(remote.stderr)
        a = (tmp_path / "local" / "report.md").read_text().split("## What was run")[0]
        b = (tmp_path / "ray" / "report.md").read_text().split("## What was run")[0]
        assert a == b
    finally:
        for n in reversed(nodes):
            n.kill(signal.SIGTERM)
        time.sleep(1)
        for n in nodes:
            n.kill(signal.SIGKILL)
        shutil.rmtree(temp, ignore_errors=True)
    assert gone(tag, 30) == []


def _on_node(pid: int, node_group: int) -> bool:
    """Whether ``pid`` runs on the node whose `ray start` leads process group ``node_group``: Ray's
    workers have sessions of their own, but their parent is the node's raylet."""
    for _ in range(4):
        try:
            if os.getpgid(pid) == node_group:
                return True
            pid = int(Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[1])
        except (OSError, ValueError):
            return False
    return False
