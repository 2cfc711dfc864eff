"""Oracle demonstrations in the replay buffer: the buffer holds exactly the replayed transitions
before learning (actions in [-1, 1] that map back onto the oracle's), the demonstration states are
neither the evaluation nor the validation states, ``--demonstrations 0`` adds none, a resume does
not add them again, and runs that cannot have them are told why."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

import asap_dsl
from asap_dsl.runs import RunDir
from asap_dsl.sampling import EVAL_SEED, task_states
from conftest import RAIL, asapc

FAST = {"net_arch": [16, 16], "learning_starts": 10_000, "batch_size": 32}  # no update within these tests


@pytest.fixture(scope="module")
def rail():
    return asap_dsl.loads(RAIL, "rail.asap")


def _learner(prog, engine: str = "sb3", n_envs: int = 2):
    """A model on the learner's environment, as a run builds them (default preset's scaling)."""
    from asap_dsl.backends.rl.config import resolve_config
    from asap_dsl.backends.rl.engines import get_engine
    from asap_dsl.backends.rl.sb3 import Scaling, ScaledVecEnv
    from asap_dsl.env import make_vec_env

    cfg = resolve_config(prog, n_envs=n_envs, settings=FAST, engine=engine)
    scaling = Scaling.for_system(prog.system, cfg.observation_scaling, cfg.action_scaling, prog.task(None).model.init_box)
    env = ScaledVecEnv(make_vec_env(prog, num_envs=n_envs, seed=0), scaling)
    model = get_engine(engine).build("sac", env, cfg.hyper, 0)
    return model, scaling, (lambda raw: ScaledVecEnv(raw, scaling))


def _buffer_rows(rb) -> tuple[np.ndarray, ...]:
    n = rb.pos  # rows written (never full here)
    flat = lambda a: a[:n].reshape(n * rb.n_envs, *a.shape[2:])  # noqa: E731
    return (flat(rb.observations), flat(rb.actions), flat(rb.rewards), flat(rb.next_observations), flat(rb.dones),
            flat(rb.timeouts))


def test_the_buffer_holds_exactly_the_replayed_oracle_sequences(rail):
    from asap_dsl.backends.oracle.solver import run
    from asap_dsl.backends.rl.demonstrations import add_demonstrations, demonstration_seed, solve

    model, scaling, wrap = _learner(rail)
    assert model.replay_buffer.pos == 0
    demos = add_demonstrations(rail, "go", model, wrap, scaling, solve(rail, "go", 24, 0, workers=1))
    assert demos.reason is None and demos.added > 10 and demos.added == demos.solved == demos.replays
    obs, acts, rew, nxt, done, _ = _buffer_rows(model.replay_buffer)
    T = demos.transitions
    assert len(obs) == -(-T // 2) * 2  # whole rows of n_envs; a last half row repeats the first transition
    assert np.array_equal(obs[T:], obs[:len(obs) - T]) and np.array_equal(acts[T:], acts[:len(obs) - T])
    obs, acts, rew, nxt, done = obs[:T], acts[:T], rew[:T], nxt[:T], done[:T]
    assert np.all(np.abs(acts) <= 1.0) and not done.any()  # a reach ends no RAIL episode (deadline 20)

    # Independently: the oracle on the same seeded states, each sequence stepped by hand.
    tm = rail.task(None).model
    states = task_states(rail.system, tm, 24, seed=demonstration_seed(0))
    report = run(rail, "go", states=states, workers=1)
    expect = []
    for r in report.results:
        if r.status == "solved" and r.actions is not None and len(r.actions) >= 1:
            x = np.array(r.x0, float)
            for a in r.actions:
                nx = x + 0.1 * 2 * np.clip(a, -1, 1)  # x' = 2u, exact for a constant input
                expect.append((scaling.observation(x[None])[0], a, scaling.observation(nx[None])[0]))
                x = nx
    assert len(expect) == T
    for (o, a, n2), o_b, a_b, n_b in zip(expect, obs, acts, nxt):
        assert np.allclose(o_b, o, atol=1e-5) and np.allclose(n_b, n2, atol=1e-4)
        assert np.allclose(scaling.action(a_b), a, atol=1e-5)  # the buffer's action is the oracle's, scaled
    goal_steps = np.cumsum([len(r.actions) for r in report.results if r.status == "solved" and len(r.actions)]) - 1
    assert np.all(rew[goal_steps] == rew.max())  # the reaching step earns r_sat


def test_a_black_box_gets_the_planners_sequences_and_the_buffer_holds_their_replays(monkeypatch):
    """A simulator's run has demonstrations too: the planner's sequences (it reaches through the
    black box), each replayed to the goal through the learner's own environment."""
    from asap_dsl.backends.rl.config import resolve_config
    from asap_dsl.backends.rl.demonstrations import add_demonstrations, solve

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parent / "fixtures"))
    from test_planner import CART, cart_minimum

    prog = asap_dsl.loads(CART % "user_sims:double_integrator", "cart.asap")
    cfg = resolve_config(prog)  # on a black box the default's come at the start, not at a stall
    assert (cfg.demonstrations, cfg.stall_demonstrations) == (300, 0)
    assert cfg.demonstration_seconds == 180.0  # the planner's budget on its clock: 36 states of 5 s
    w = solve(prog, "reach", 4, 0, workers=2, state_seconds=0.5, cache=False)
    assert w.reason is None and w.solved == len(w.sequences) >= 3
    for x0, seq in zip(w.starts, w.sequences):  # reached, and no later than the minimum's bound allows
        assert len(seq) >= cart_minimum(*map(float, x0))
    model, scaling, wrap = _learner(prog)
    demos = add_demonstrations(prog, "reach", model, wrap, scaling, w)
    assert demos.added == len(w.sequences) and demos.transitions == sum(len(q) for q in w.sequences)
    rew = _buffer_rows(model.replay_buffer)[2][:demos.transitions]
    assert np.sum(rew == rew.max()) >= demos.added  # every replay reaches (r_sat)


def test_under_a_time_limit_the_planners_budget_caps_its_wall_time(monkeypatch):
    """A run with a time limit lives on the wall clock: its black box's search stops once the
    budget's wall seconds are spent (a spent budget: no state), where without it the budget only
    sets the count; the log line says which."""
    from asap_dsl.backends.rl.demonstrations import search_budget_text, solve

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parent / "fixtures"))
    from test_planner import CART

    prog = asap_dsl.loads(CART % "user_sims:double_integrator", "cart.asap")
    capped = solve(prog, "reach", 4, 0, workers=1, state_seconds=0.5, budget_seconds=1e-9, wall_capped=True,
                   cache=False)
    free = solve(prog, "reach", 4, 0, workers=1, state_seconds=0.5, budget_seconds=1e-9, cache=False)
    assert capped.states == 0 and capped.sequences == []
    assert free.states == 1 and free.solved == 1  # the count's floor: one state, searched in full
    assert search_budget_text(prog, 90.0, 5.0, wall_capped=True).endswith("for at most 90 s")
    assert "at most" not in search_budget_text(prog, 90.0, 5.0)


def test_the_planners_count_is_the_budgets_whatever_the_cores(monkeypatch):
    """A sweep's one-core worker searches as many states as a two-core run (the budget is CPU
    seconds): a count that followed the cores gave the swimmer's seed 1 six solved states."""
    from asap_dsl import limits
    from asap_dsl.backends.rl.demonstrations import search_count

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parent / "fixtures"))
    from test_planner import CART

    prog = asap_dsl.loads(CART % "user_sims:double_integrator", "cart.asap")
    counts = set()
    for cores in (1, 2, 8):
        monkeypatch.setattr(limits, "available_cores", lambda c=cores: c)
        counts.add(search_count(prog, 300, 5.0, 180.0))
    assert counts == {36}
    assert search_count(prog, 20, 5.0, 180.0) == 20 and search_count(prog, 300, 5.0, None) == 300


def test_demonstration_states_are_not_evaluation_or_validation_states(rail):
    from asap_dsl.backends.rl.config import VALIDATION_SEED
    from asap_dsl.backends.rl.demonstrations import demonstration_seed

    assert all(demonstration_seed(s) not in (EVAL_SEED, VALIDATION_SEED) for s in range(5000))
    tm = rail.task(None).model
    demo = task_states(rail.system, tm, 256, seed=demonstration_seed(0))
    for seed in (EVAL_SEED, VALIDATION_SEED):
        other = task_states(rail.system, tm, 1000, seed=seed)
        assert not np.isin(demo.ravel(), other.ravel()).any()


def test_who_gets_demonstrations(rail):
    from asap_dsl.backends.rl.config import ConfigError, resolve_config

    td3 = resolve_config(rail, algo="td3")
    assert td3.demonstrations == 0 and td3.stall_demonstrations == 300  # the default's come when the run stalls (below)
    sac = resolve_config(rail)  # ... and SAC's imitated paths at the start as well (tests/test_imitation.py)
    assert (sac.demonstrations, sac.imitation, sac.stall_demonstrations) == (2500, 0.1, 300)
    assert resolve_config(rail, preset="paper").demonstrations == 0
    assert resolve_config(rail, demonstrations=12).demonstrations == 12
    assert resolve_config(rail, algo="td3", demonstrations=12, preset="paper").demonstrations == 12
    with pytest.raises(ConfigError, match="ppo has no replay buffer"):
        resolve_config(rail, algo="ppo", demonstrations=8)
    with pytest.raises(ConfigError, match="0 or more"):
        resolve_config(rail, demonstrations=-1)


def test_zero_adds_none_and_a_resume_does_not_add_them_again(rail, tmp_path, capsys):
    spec = tmp_path / "rail.asap"
    spec.write_text(RAIL.replace("tolerances 20, 10, 5", "tolerances 20, 10, 5\n  train { learning_starts = 10000 }"))
    base = ["train", spec, "--steps", 40, "--envs", 2, "--engine", "sb3", "--no-eval"]

    def buffer_pos(out) -> int:
        with open(out / "checkpoint" / "replay.pkl", "rb") as f:
            return int(pickle.load(f).pos)

    code, _, err = asapc(capsys, *base, "--demonstrations", 0, "--out", tmp_path / "off")
    assert code == 0 and "demonstrations" not in err
    assert RunDir(tmp_path / "off").read_manifest()["config"]["demonstrations"] == 0
    assert buffer_pos(tmp_path / "off") == 40 // 2  # the run's own steps only

    out = tmp_path / "on"
    code, _, err = asapc(capsys, *base, "--demonstrations", 16, "--out", out)
    assert code == 0 and "demonstrations: " in err and " transitions in the replay buffer" in err
    manifest = RunDir(out).read_manifest()
    slots = -(-manifest["demonstrations"]["transitions"] // 2)
    assert manifest["config"]["demonstrations"] == 16 and slots > 0
    assert buffer_pos(out) == slots + 40 // 2
    code, _, err = asapc(capsys, "train", spec, "--out", out, "--resume", "--steps", 80, "--no-eval")
    assert code == 0 and "demonstrations" not in err
    assert buffer_pos(out) == slots + 80 // 2


def test_sbx_models_take_them_through_the_same_api():
    """What add_demonstrations uses of a model: SB3's off-policy loop and ReplayBuffer, and the
    policy's scale_action (building an sbx model compiles for seconds: the runs measure that)."""
    pytest.importorskip("sbx")
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
    from stable_baselines3.common.policies import BasePolicy

    from asap_dsl.backends.rl.engines import get_engine

    for algo in ("sac", "td3", "ddpg"):
        cls = get_engine("sbx")._model_class(algo)
        assert issubclass(cls, OffPolicyAlgorithm) and issubclass(cls.policy_aliases["MlpPolicy"], BasePolicy)


def test_a_replay_that_ends_its_episode_stores_the_terminal_observation_and_the_timeout(rail):
    from asap_dsl.backends.oracle.solver import run
    from asap_dsl.backends.rl.demonstrations import replay

    _, scaling, wrap = _learner(rail)
    states = np.array([[-0.5], [0.2], [1.0]])  # the last starts in the goal: nothing to replay, dropped below
    seqs = [np.asarray(r.actions, float) for r in run(rail, "go", states=states[:2], workers=1).results]
    tr, reached = replay(rail, "go", None, wrap, scaling.policy_action, lambda u: u, states[:2], seqs,
                         np.array([len(s) for s in seqs]))  # episodes exactly as long as the sequences
    assert reached.all() and len(tr) == sum(map(len, seqs))
    ends = np.cumsum([len(s) for s in seqs]) - 1
    assert tr.dones[ends].all() and tr.timeouts[ends].all() and not tr.dones[:ends[0]].any()
    # The next observation of a time-out is where the episode ended (in the goal), not the reset state.
    last = scaling.obs_centre + tr.next_obs[ends].astype(float) * scaling.obs_half
    assert np.all(np.abs(last[:, 0] - 1.0) <= 0.2 + 1e-6)


# ------------------------------------------------------------------ sparse goals (exploration.py)
def test_the_late_rule_is_the_default_presets_unless_a_run_chooses_its_demonstrations(rail):
    from asap_dsl.backends.rl.config import resolve_config

    assert resolve_config(rail).late_demonstrations == 8
    assert resolve_config(rail, demonstrations=0).late_demonstrations == 0  # the run chose: none
    assert resolve_config(rail, demonstrations=4).late_demonstrations == 0
    assert resolve_config(rail, preset="paper").late_demonstrations == 0
    assert resolve_config(rail, algo="ppo").late_demonstrations == 0  # no replay buffer: no rule


def test_the_presets_demonstrations_wait_for_a_stall_unless_a_run_asks_for_its_own(rail):
    """On known dynamics the default's demonstrations come once validation stalls (one state per 800 steps, at most
    300), not at the start; ``--demonstrations N`` puts N at the start and no rule."""
    from asap_dsl.backends.rl.config import resolve_config

    cfg = resolve_config(rail, steps=80_000, algo="td3")  # SAC imitates the oracle's paths from the start too
    assert (cfg.demonstrations, cfg.stall_demonstrations) == (0, 100)
    assert resolve_config(rail, algo="td3").stall_demonstrations == 300
    assert (resolve_config(rail, algo="td3", demonstrations=4).demonstrations,
            resolve_config(rail, algo="td3", demonstrations=4).stall_demonstrations) == (4, 0)
    assert resolve_config(rail, demonstrations=0).stall_demonstrations == 0
    assert resolve_config(rail, preset="paper").stall_demonstrations == 0
    assert resolve_config(rail, algo="ppo").stall_demonstrations == 0
    assert "stall_demonstrations" not in resolve_config(rail, preset="paper").key  # runs made before keep their key


def test_the_late_rule_fires_once_when_nothing_has_succeeded_after_its_share_of_the_budget():
    from asap_dsl.backends.rl.exploration import LateDemonstrations

    rule = LateDemonstrations(8, 0.1)
    zero, hit = {"rates": {5: 0.0, 10: 0.0}}, {"rates": {5: 0.0, 10: 0.01}}
    assert not rule.due([zero], 99, 1000, 1.0, None)           # 9.9% of the steps
    assert rule.due([zero, zero], 100, 1000, 1.0, None)
    assert not rule.due([zero, hit, zero], 500, 1000, 1.0, None)  # one state reached once: exploration works
    assert rule.due([zero], 10, 1000, 6.0, 60.0)               # a time-limited run: 10% of its time
    assert not LateDemonstrations(0, 0.1).due([zero], 900, 1000, 1.0, None)
    rule.restore({"added": 3, "at_step": 100, "why": "nothing found"})  # a checkpoint from before the list
    assert not rule.due([zero], 900, 1000, 1.0, None)          # once per run


def test_the_rule_fires_on_a_stall_once_validation_has_stopped_improving():
    from asap_dsl.backends.rl.exploration import NOTHING, STALLED, LateDemonstrations

    def rows(*scores):
        return [{"steps": 100 * (i + 1), "score": s, "rates": {5: s, 10: s}} for i, s in enumerate(scores)]

    rule = LateDemonstrations(8, 0.1, 300, 0.5)
    assert rule.waits_for_stall
    assert rule.due(rows(0.0, 0.0), 200, 10_000, 1.0, None) is None  # nothing found, but not 10% of the budget
    assert rule.due(rows(0.0, 0.0, 0.0), 1000, 10_000, 1.0, None) == NOTHING
    assert rule.due(rows(0.2, 0.5, 0.6), 300, 10_000, 1.0, None) is None   # still improving
    assert rule.due(rows(0.2, 0.5, 0.6, 0.6, 0.6, 0.6), 600, 10_000, 1.0, None) == STALLED  # flat for half its steps
    # ... but not in the run's last validation interval: 180 s of search that nothing would learn from
    assert rule.due(rows(0.2, 0.5, 0.6, 0.6, 0.6, 0.6), 600, 650, 1.0, None, interval=100) is None
    assert rule.due(rows(0.0, 0.0, 0.0), 1000, 1050, 1.0, None, interval=100) is None
    assert LateDemonstrations(8, 0.1).due(rows(0.2, 0.5, 0.6, 0.6, 0.6, 0.6), 600, 10_000, 1.0, None) is None
    assert rule.due(rows(0.2, 1.0, 1.0, 1.0, 1.0, 1.0), 600, 10_000, 1.0, None) is None  # nothing left to gain
    assert not rule.may_fire(rows(0.2, 1.0, 1.0, 1.0, 1.0, 1.0))  # ... so the run may end on its plateau
    rule.added = [{"added": 3, "at_step": 600, "why": STALLED}]
    assert not rule.waits_for_stall and rule.due(rows(0.2, 0.5, 0.6, 0.6, 0.6, 0.6), 600, 10_000, 1.0, None) is None


def test_a_run_that_found_nothing_can_still_stall_and_each_trigger_fires_once():
    """The sparse goal's few sequences first; once the run's own successes stop improving, the
    stall's. Each is judged on the validations after the latest firing."""
    from asap_dsl.backends.rl.exploration import NOTHING, STALLED, LateDemonstrations

    def rows(*scores, start=0):
        return [{"steps": start + 100 * (i + 1), "score": s, "rates": {5: s, 10: s}} for i, s in enumerate(scores)]

    rule = LateDemonstrations(8, 0.1, 300, 0.5, sparse_gamma=0.99)
    zeros = rows(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert rule.due(zeros, 1000, 10_000, 1.0, None) == NOTHING
    rule.added.append({"at_step": 1000, "why": NOTHING, "gamma": 0.99})
    assert rule.gamma == 0.99 and rule.due(zeros, 1100, 10_000, 1.0, None) is None  # never twice
    assert rule.may_fire(zeros + rows(0.1, 0.2, start=1000))
    # Flat since the firing for half the steps: the stall; the validations of nothing before it do not count.
    later = zeros + rows(0.1, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, start=1000)
    assert rule.due(later, 2100, 10_000, 1.0, None) is None  # best at 1200: not half of 2100 ago
    assert rule.due(later + rows(0.3, 0.3, 0.3, start=2100), 2400, 10_000, 1.0, None) == STALLED
    rule.added.append({"at_step": 2400, "why": STALLED})
    assert rule.since == 2400 and not rule.may_fire(later) and rule.gamma == 0.99
    # Still nothing after the first few sequences (the puck's detour): that is a stall too.
    rule = LateDemonstrations(8, 0.1, 300, 0.5, added=[{"at_step": 1000, "why": NOTHING}])
    still = zeros + rows(*[0.0] * 11, start=1000)
    assert rule.may_fire(still) and rule.due(still, 2100, 10_000, 1.0, None) is None
    assert rule.due(still + rows(0.0, start=2100), 2200, 10_000, 1.0, None) == STALLED


def _saved_gamma(out) -> float:
    """The discount in a run's checkpoint model (stable-baselines3's zip keeps its attributes)."""
    import json
    import zipfile

    with zipfile.ZipFile(out / "checkpoint" / "model.zip") as z:
        return float(json.loads(z.read("data"))["gamma"])


def test_a_run_that_finds_nothing_gets_the_oracles_sequences_once(tmp_path, capsys, monkeypatch):
    """A goal that an untrained policy never reaches (no updates: learning starts after the run)
    gets the oracle's sequences at the first validation after 10% of the steps, recorded in the
    manifest and the checkpoint, so that a resume does not add them again; where validation
    succeeds from the start the rule never fires."""
    far = RAIL.replace("init [-1.5, 1.5]", "init [-1.5, -0.5]").replace(
        "tolerances 20, 10, 5", "tolerances 20, 10, 5\n  train { learning_starts = 10000 }")
    spec = tmp_path / "far.asap"
    spec.write_text(far)
    out = tmp_path / "far"

    def buffer_pos() -> int:
        with open(out / "checkpoint" / "replay.pkl", "rb") as f:
            return int(pickle.load(f).pos)

    # Validation may step its states as many steps as training took: on this short run the second
    # validation would come at the last step (the rule would never fire): here it may take more.
    from asap_dsl.backends.rl import validation

    monkeypatch.setattr(validation, "BUDGET", 1e9)
    STEPS = 8000
    base = ["train", spec, "--envs", 2, "--engine", "sb3", "--no-eval", "--out", out]
    code, _, err = asapc(capsys, *base, "--steps", STEPS)
    assert code == 0 and "no validation has succeeded after" in err, err
    late = RunDir(out).read_manifest()["late_demonstrations"][0]
    assert 300 <= late["at_step"] < STEPS and late["states"] == 8 and late["added"] == 8 and late["oracle_seconds"] > 0
    assert late["why"] == "nothing found" and "demonstrations" not in RunDir(out).read_manifest()  # none at the start
    # The discount's horizon grew to the deadline, in the model the run keeps and resumes.
    config = RunDir(out).read_manifest()["config"]
    assert late["gamma"] == config["sparse_gamma"] > config["hyper"]["gamma"]
    assert "discount's horizon grows to the deadline" in err and _saved_gamma(out) == late["gamma"]
    assert RunDir(out).read_manifest()["seconds"] >= late["seconds"]  # the search is the run's time, cached or not

    def slots() -> int:  # the rows of every firing: still nothing found, the run may stall and get the stall's too
        firings = RunDir(out).read_manifest()["late_demonstrations"]
        assert [r["why"] for r in firings] in (["nothing found"], ["nothing found", "stalled"])
        return sum(-(-r["transitions"] // 2) for r in firings)

    # the run's own steps after them. It may end early on the plateau (nothing learns without
    # updates): a callback that stops the run does so before stable-baselines3 stores that step.
    def done() -> int:
        m = RunDir(out).read_manifest()
        return m["steps_done"] // 2 - ("plateau_step" in m)

    assert buffer_pos() == slots() + done()
    code, _, err = asapc(capsys, "train", spec, "--out", out, "--resume", "--steps", STEPS + 60, "--no-eval")
    assert code == 0 and "no validation has succeeded after" not in err
    assert buffer_pos() == slots() + done()  # within the buffer the run was sized for
    assert _saved_gamma(out) == late["gamma"]

    near = tmp_path / "near.asap"  # half the init box starts in the goal: validation succeeds
    near.write_text(far.replace("init [-1.5, -0.5]", "init [0.8, 1.6]"))
    code, _, err = asapc(capsys, "train", near, "--steps", 400, "--envs", 2, "--engine", "sb3", "--no-eval",
                         "--out", tmp_path / "near")
    assert code == 0 and "no validation has succeeded" not in err
    assert "late_demonstrations" not in RunDir(tmp_path / "near").read_manifest()


def test_a_run_whose_validation_stalls_gets_the_oracles_longest_sequences_once(tmp_path, capsys, monkeypatch):
    """Validation succeeds from the start and never moves (no updates): the rule fires on the
    stall, with the preset's share of the states (one per 800 steps), the longest fifth of their
    sequences four times each, recorded in the manifest; the run is not ended on its plateau
    before that, and a resume does not fire it again."""
    near = RAIL.replace("init [-1.5, 1.5]", "init [0.8, 1.6]").replace(
        "tolerances 20, 10, 5", "tolerances 20, 10, 5\n  train { learning_starts = 10000 }")
    spec = tmp_path / "near.asap"
    spec.write_text(near)
    out = tmp_path / "near"
    from asap_dsl.backends.rl import validation

    monkeypatch.setattr(validation, "BUDGET", 1e9)  # enough validations in a fast run (see above)
    STEPS = 8000
    code, _, err = asapc(capsys, "train", spec, "--steps", STEPS, "--envs", 2, "--engine", "sb3", "--no-eval",
                         "--out", out)
    assert code == 0 and "validation stopped improving after" in err, err
    m = RunDir(out).read_manifest()
    late = m["late_demonstrations"][0]
    assert late["why"] == "stalled" and "gamma" not in late and late["states"] == STEPS // 800 and late["replays"] % 4 == 0
    assert late["at_step"] < m["steps_done"] and m.get("plateau_step", STEPS) > late["at_step"]
    code, _, err = asapc(capsys, "train", spec, "--out", out, "--resume", "--steps", STEPS + 600, "--no-eval")
    assert code == 0 and "validation stopped improving after" not in err


def test_a_second_run_of_the_same_seed_reads_the_sequences_back_and_is_charged_their_time(rail, monkeypatch):
    from asap_dsl.backends.oracle import solver
    from asap_dsl.backends.rl.demonstrations import solve

    first = solve(rail, "go", 12, 5, workers=1, budget_seconds=60.0)
    assert not first.cached and first.sequences and first.oracle_seconds > 0

    def no_oracle(*_a, **_k):
        raise AssertionError("the oracle ran again")

    monkeypatch.setattr(solver, "run", no_oracle)
    again = solve(rail, "go", 12, 5, workers=1, budget_seconds=60.0)
    assert again.cached and again.oracle_seconds == pytest.approx(first.oracle_seconds)
    assert np.array_equal(again.starts, first.starts) and np.array_equal(again.lengths, first.lengths)
    assert all(np.array_equal(a, b) for a, b in zip(again.sequences, first.sequences))
    with pytest.raises(AssertionError, match="ran again"):  # another budget is another search
        solve(rail, "go", 12, 5, workers=1, budget_seconds=30.0)
    with pytest.raises(AssertionError, match="ran again"):
        solve(rail, "go", 12, 5, workers=1, budget_seconds=60.0, cache=False)


def test_the_demonstrations_stay_in_the_buffer_once_it_wraps_round():
    """A ring buffer forgets its oldest rows first: the demonstrations, stored before learning.
    ``keep`` (called before each store, as the run's callback does) starts the next round after
    them; where they would fill half the buffer or more, the buffer is left as it is."""
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer

    from asap_dsl.backends.rl.demonstrations import keep

    box = spaces.Box(-1, 1, (1,), np.float32)
    rb = ReplayBuffer(10, box, box, n_envs=1)

    def add(v: float) -> None:
        keep(rb, [(0, 3)])
        rb.add(np.array([[v]]), np.array([[v]]), np.array([[0.0]]), np.array([0.0]), np.array([False]), [{}])

    for v in (100, 101, 102):  # the demonstrations
        rb.add(np.array([[v]]), np.array([[v]]), np.array([[0.0]]), np.array([0.0]), np.array([False]), [{}])
    for v in range(25):  # the learner's own, well past a wrap
        add(float(v))
    assert list(rb.observations[:3, 0, 0]) == [100, 101, 102]
    assert set(rb.observations[3:, 0, 0]) == set(range(18, 25))  # the latest seven of the learner's
    big = ReplayBuffer(4, box, box, n_envs=1)
    big.full, big.pos = True, 0
    keep(big, [(0, 2)])  # half of the buffer: not kept
    assert big.pos == 0


def test_rows_stored_mid_run_stay_in_the_buffer_once_it_wraps_round():
    """The late rule stores the paths the actor imitates mid-run, after the learner's first rows:
    the ring skips them too (before, it overwrote them a round later and the actor imitated
    whatever took their place), and a range that ends at the buffer's end sends it to row 0."""
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer

    from asap_dsl.backends.rl.demonstrations import keep

    box = spaces.Box(-1, 1, (1,), np.float32)

    def fill(rb, start: int, rows: int, learner: int, demos: int) -> None:
        for v in range(learner):
            if v == start:  # the firing: its rows follow the learner's first ones
                for d in range(rows):
                    rb.add(np.array([[demos + d]]), np.array([[0.0]]), np.array([[0.0]]), np.array([0.0]),
                           np.array([False]), [{}])
            keep(rb, [(start, rows)])
            rb.add(np.array([[v]]), np.array([[0.0]]), np.array([[0.0]]), np.array([0.0]), np.array([False]), [{}])

    rb = ReplayBuffer(10, box, box, n_envs=1)
    fill(rb, 4, 3, 40, 100)
    assert list(rb.observations[4:7, 0, 0]) == [100, 101, 102]
    assert set(rb.observations[[0, 1, 2, 3, 7, 8, 9], 0, 0]) == set(range(33, 40))  # the learner's latest seven
    tail = ReplayBuffer(10, box, box, n_envs=1)
    fill(tail, 7, 3, 40, 100)
    assert list(tail.observations[7:, 0, 0]) == [100, 101, 102] and set(tail.observations[:7, 0, 0]) == set(range(33, 40))
    both = ReplayBuffer(10, box, box, n_envs=1)  # the start's rows and a range that ends at the buffer's end
    both.full, both.pos = True, 8
    keep(both, [(0, 2), (7, 3)])
    assert both.pos == 2


def test_make_room_grows_a_buffer_that_has_not_wrapped_and_leaves_one_that_has():
    """The late rule's paths for the actor to imitate come mid-run: the buffer grows by their rows
    (what it held stays where it was), unless it has wrapped round already."""
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer

    from asap_dsl.backends.rl.demonstrations import make_room

    box = spaces.Box(-1, 1, (1,), np.float32)
    rb = ReplayBuffer(10, box, box, n_envs=2)  # 5 rows of 2
    for v in range(3):
        rb.add(np.full((2, 1), v), np.full((2, 1), v), np.zeros((2, 1)), np.zeros(2), np.zeros(2, bool), [{}, {}])
    make_room(rb, 7)  # 7 transitions: 4 rows of 2
    assert rb.buffer_size == 9 and rb.pos == 3 and not rb.full
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
        assert getattr(rb, name).shape[0] == 9, name
    assert list(rb.observations[:3, 0, 0]) == [0, 1, 2] and not rb.observations[3:].any()
    rb.full, rb.pos = True, 1
    make_room(rb, 7)
    assert rb.buffer_size == 9


def test_a_run_on_sbx_that_finds_nothing_imitates_the_oracles_paths_from_then_on(tmp_path, capsys, monkeypatch):
    """On SAC with sbx the late rule's search is the imitation's (the preset's states within its
    budget, spawned workers since JAX is loaded): its paths go into rows the buffer grows by, the
    manifest records where, and a resume neither searches again nor forgets them."""
    from dataclasses import replace

    from asap_dsl.backends.rl import presets, validation

    monkeypatch.setattr(validation, "BUDGET", 1e9)
    monkeypatch.setitem(presets.PRESETS, "default",
                        replace(presets.DEFAULT, imitation=0.0, policy_search=None, imitation_states=12,
                                imitation_seconds=120.0, plateau=None))  # the late rule: no imitation from the start
    far = RAIL.replace("init [-1.5, 1.5]", "init [-1.5, -0.5]").replace(
        "tolerances 20, 10, 5", "tolerances 20, 10, 5\n  train { learning_starts = 10000 }")
    spec = tmp_path / "far.asap"
    spec.write_text(far)
    out = tmp_path / "far"
    STEPS = 8000
    code, _, err = asapc(capsys, "train", spec, "--envs", 2, "--no-eval", "--out", out, "--steps", STEPS)
    assert code == 0 and "the actor imitates these paths from now on (weight 1)" in err, err
    m = RunDir(out).read_manifest()
    late = m["late_demonstrations"][0]
    assert m["config"]["sparse_imitation"] == 1.0 and m["config"]["sparse_gamma"] is None
    assert late.get("gamma") is None and "discount's horizon grows" not in err  # shown the detour, it keeps its discount
    assert late["why"] == "nothing found" and late["imitation"] == 1.0 and late["states"] == 12 and late["added"] >= 10
    with open(out / "checkpoint" / "replay.pkl", "rb") as f:
        rb = pickle.load(f)
    # Their rows follow the learner's own, in room made for them: nothing of either is overwritten.
    assert late["start_row"] > 0 and late["rows"] == -(-late["transitions"] // 2)
    # (a stall may have fired after it too: its rows are in the count)
    firings = sum(r["rows"] for r in m["late_demonstrations"])
    assert not rb.full and rb.pos == firings + m["steps_done"] // 2 - ("plateau_step" in m)
    stored = rb.actions[late["start_row"]:late["start_row"] + late["rows"]]
    assert np.abs(stored).max() <= 1.0 and np.abs(stored).max() > 0  # the oracle's actions, in the policy's units
    from asap_dsl.backends.rl import session as session_module

    kept = set()
    real_keep = session_module.keep
    monkeypatch.setattr(session_module, "keep", lambda rb, ranges: (kept.update(ranges), real_keep(rb, ranges)))
    code, _, err = asapc(capsys, "train", spec, "--out", out, "--resume", "--steps", STEPS + 60, "--no-eval")
    assert code == 0 and "no validation has succeeded after" not in err, err
    assert (late["start_row"], late["rows"]) in kept  # resumed, the ring still skips the imitated rows
