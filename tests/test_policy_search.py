"""The policy search after the learner (backends/rl/policy_search.py): its settings, its steps, and
its place in a run (kept only if it beats the learner on validation, resumed exactly)."""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

import asap_dsl
from asap_dsl.backends.rl.config import ConfigError, resolve_config
from asap_dsl.runs import RunDir

from conftest import RAIL

pytest.importorskip("sbx")

FAST = {"learning_starts": 100, "batch_size": 64, "net_arch": [32, 32]}


def _search(settings, seed: int = 0):
    """A policy search on the rail from an untrained SAC actor, judged on 200 validation states."""
    from asap_dsl.backends.rl.engines import get_engine
    from asap_dsl.backends.rl.policy_search import ActorFamily, PolicySearch
    from asap_dsl.backends.rl.sb3 import Scaling, ScaledVecEnv
    from asap_dsl.backends.rl.validation import validation_score
    from asap_dsl.env import make_vec_env
    from asap_dsl.rollout import Evaluator
    from asap_dsl.sampling import task_states

    prog = asap_dsl.loads(RAIL, "rail.asap")
    cfg = resolve_config(prog, steps=2000)
    task = prog.task(None).model
    scaling = Scaling.for_run(prog.system, cfg, task.init_box)
    env = ScaledVecEnv(make_vec_env(prog, cfg.task, num_envs=2, seed=0), scaling)
    model = get_engine("sbx").build("sac", env, cfg.hyper, seed)
    validator = Evaluator(prog, cfg.task, task_states(prog.system, task, 200, seed=7), reward=cfg.reward)
    family = ActorFamily(model, "sac", scaling)
    search = PolicySearch(prog, cfg.task, settings, family, validator, validation_score, reward=cfg.reward,
                          gamma=0.9, failure_reward=None, seed=seed)
    return search, model


def test_the_search_climbs_the_arrival_from_an_untrained_actor():
    from asap_dsl.backends.rl.policy_search import SearchSettings

    search, _ = _search(SearchSettings(iterations=40, population=32, batch=64, sigma=0.1, learning_rate=0.03))
    state = search.start(0.0)
    before = search.validate(state)["score"]
    for _ in range(40):
        state = search.iterate(state)
    after = search.validate(state)["score"]
    assert after > before + 0.3, (before, after)
    assert state.best_iteration == 40 and state.best_score == pytest.approx(after, abs=1e-6)


def test_an_iteration_depends_on_its_state_alone():
    import pickle
    from dataclasses import asdict

    from asap_dsl.backends.rl.policy_search import SearchSettings, SearchState

    settings = SearchSettings(iterations=4, population=8, batch=16, objective="return")  # no ties: it moves
    search, _ = _search(settings)
    straight = search.start(0.0)
    for _ in range(4):
        straight = search.iterate(straight)
    halfway = search.start(0.0)
    for _ in range(2):
        halfway = search.iterate(halfway)
    kept = pickle.loads(pickle.dumps(asdict(halfway)))  # as a checkpoint keeps it
    again, _ = _search(settings)  # a new process's search
    resumed = SearchState(**kept)
    for _ in range(2):
        resumed = again.iterate(resumed)
    assert resumed.iteration == 4
    np.testing.assert_array_equal(resumed.theta, straight.theta)
    np.testing.assert_array_equal(resumed.second, straight.second)
    assert not np.array_equal(straight.theta, search.family.theta0)


@pytest.mark.parametrize("algo", ["sac", "td3", "ddpg"])
def test_the_family_acts_as_the_policy_the_run_evaluates(algo):
    from asap_dsl.backends.rl.engines import get_engine
    from asap_dsl.backends.rl.policy_search import ActorFamily
    from asap_dsl.backends.rl.sb3 import PolicyController, Scaling, ScaledVecEnv
    from asap_dsl.env import make_vec_env

    prog = asap_dsl.loads(RAIL, "rail.asap")
    cfg = resolve_config(prog, steps=2000, algo=algo)
    scaling = Scaling.for_run(prog.system, cfg, prog.task(None).model.init_box)
    model = get_engine("sbx").build(algo, ScaledVecEnv(make_vec_env(prog, cfg.task, num_envs=2, seed=0), scaling),
                                    cfg.hyper, 1)
    obs = np.random.default_rng(0).uniform(-2, 2, size=(64, 1))  # the rail observes x
    family = ActorFamily(model, algo, scaling)
    want = PolicyController(model, scaling).act(obs, obs, 0)
    np.testing.assert_allclose(family.act(obs, obs, 0), want, atol=1e-5)
    family.thetas = np.stack([family.theta0, family.theta0 + 0.5])  # two candidates, a block of rows each
    both = family.act(np.concatenate([obs, obs]), None, 0)
    np.testing.assert_allclose(both[:64], want, atol=1e-5)
    assert np.abs(both[64:] - want).max() > 1e-3
    family.install(model, family.theta0 + 0.5)  # what the run saves is what the candidate did
    np.testing.assert_allclose(PolicyController(model, scaling).act(obs, obs, 0), both[64:], atol=1e-5)


def test_tied_candidates_pull_no_way():
    from asap_dsl.backends.rl.policy_search import centred_ranks

    assert np.all(centred_ranks(np.full(6, 21.0)) == 0.0)
    r = centred_ranks(np.array([1.0, 3.0, 3.0, 2.0]))
    np.testing.assert_allclose(r, [-0.5, 1 / 3, 1 / 3, -1 / 6])
    assert r.sum() == pytest.approx(0.0)


@pytest.mark.parametrize("change, words", [
    ({"population": 7}, "population an even one"),
    ({"sigma": -0.1}, "sigma and learning_rate"),
    ({"learning_rate": float("nan")}, "sigma and learning_rate"),
    ({"objective": "speed"}, "one of arrival, return, tolerances"),
    ({"max_smoothing_loss": -0.01}, "max_smoothing_loss takes a finite number of at least 0"),
    ({"time_share": 1.0}, "time_share"),
    ({"gait": 3}, "no setting gait"),
    ({"action_gains": [1.0, 0.9]}, "action_gains take numbers of at least 1"),
    ({"action_gains": [1.0, 1.1, 1.2]}, "as many as divide its population"),
    ({"action_gains": [1.0, float("inf")]}, "action_gains"),
])
def test_bad_settings_are_refused_in_words(change, words):
    from asap_dsl.backends.rl.policy_search import SearchSettings

    with pytest.raises(ValueError, match=words):
        SearchSettings.from_dict({**SearchSettings().to_dict(), **change})


def test_the_run_configuration_of_the_search():
    prog = asap_dsl.loads(RAIL, "rail.asap")
    cfg = resolve_config(prog, steps=40_000, search_iterations=7)
    assert cfg.policy_search["iterations"] == 7 and cfg.key["policy_search"]["iterations"] == 7
    assert resolve_config(prog, steps=40_000, search_iterations=0).policy_search is None
    assert "policy_search" not in resolve_config(prog, steps=40_000, search_iterations=0).key  # runs before it match
    with pytest.raises(ConfigError, match="SAC, TD3 or DDPG on the sbx engine; this run trains PPO"):
        resolve_config(prog, steps=40_000, algo="ppo", search_iterations=5)
    with pytest.raises(ConfigError, match="whole number, 0 or more"):
        resolve_config(prog, steps=40_000, search_iterations=-1)
    assert resolve_config(prog, steps=40_000, algo="td3", search_iterations=5).policy_search["iterations"] == 5


def test_the_search_in_a_run_is_kept_only_if_it_beats_the_learner(tiny, tmp_path):
    out = tmp_path / "run"
    res = asap_dsl.train(tiny, steps=600, n_envs=2, out=out, settings=FAST, evaluate=False, search_iterations=30)
    manifest = RunDir(out).read_manifest()
    record = manifest["policy_search"]
    assert res.status == "finished" and record["iterations"] == 30 and len(record["validations"]) == 2
    learner = max(r["score"] for r in res.curves)
    assert record["score_before"] == pytest.approx(learner)
    if record["kept_iteration"] is None:
        assert manifest["best"]["score"] == pytest.approx(learner) and "search_iteration" not in manifest["best"]
    else:
        kept = next(r for r in record["validations"] if r["iteration"] == record["kept_iteration"])
        assert kept["score"] > learner and manifest["best"]["score"] == pytest.approx(kept["score"])
        assert manifest["best"]["search_iteration"] == record["kept_iteration"]
    # The kept model is what evaluation loads: its validation is the record's.
    from asap_dsl.backends.rl.evaluation import load_run
    from asap_dsl.rollout import Evaluator
    from asap_dsl.sampling import task_states

    loaded = load_run(out)
    prog = loaded.program
    task = prog.task(None).model
    states = task_states(prog.system, task, loaded.config.validation_episodes, seed=7)
    rates = Evaluator(prog, "go", states, reward=loaded.config.reward).run(loaded.controller())
    assert np.mean([rates.rate(T) for T in (5, 10, 20)]) == pytest.approx(manifest["best"]["score"], abs=1e-6)
    # Resumed once done: nothing more to do.
    again = asap_dsl.train(tiny, out=out, resume=True, evaluate=False)
    assert again.status == "finished" and RunDir(out).read_manifest()["policy_search"] == record
    # Resumed with more steps: the learner trains them, then a new search from the best model.
    more = asap_dsl.train(tiny, out=out, resume=True, steps=800, evaluate=False)
    assert more.status == "finished" and more.steps == 800 and max(r["steps"] for r in more.curves) == 800
    again = RunDir(out).read_manifest()["policy_search"]
    assert again["iterations"] == 30 and again["score_before"] >= record["score"] - 1e-9


def test_a_search_stopped_midway_resumes_where_it_stopped(tiny, tmp_path, monkeypatch):
    from asap_dsl.backends.rl import policy_search as ps

    straight = tmp_path / "straight"
    asap_dsl.train(tiny, steps=600, n_envs=2, out=straight, settings=FAST, evaluate=False, search_iterations=30)
    iterate = ps.PolicySearch.iterate

    def stopping(self, state):  # SIGTERM, as a scheduler sends it, after the 12th iteration
        state = iterate(self, state)
        if state.iteration == 12:
            os.kill(os.getpid(), signal.SIGTERM)
        return state

    out = tmp_path / "stopped"
    monkeypatch.setattr(ps.PolicySearch, "iterate", stopping)
    res = asap_dsl.train(tiny, steps=600, n_envs=2, out=out, settings=FAST, evaluate=False, search_iterations=30)
    assert res.status == "interrupted"
    state = json.loads((out / "checkpoint" / "state.json").read_text())
    assert state["policy_search"]["iteration"] == 12 and state["learned"] is True
    monkeypatch.setattr(ps.PolicySearch, "iterate", iterate)
    res = asap_dsl.train(tiny, out=out, resume=True, evaluate=False)
    assert res.status == "finished" and res.steps == 600  # the learner did not train again
    a, b = (RunDir(p).read_manifest()["policy_search"] for p in (straight, out))
    assert [r["score"] for r in a["validations"]] == [r["score"] for r in b["validations"]]
    assert a["kept_iteration"] == b["kept_iteration"]


def test_a_time_limited_run_leaves_the_search_its_share(tiny, tmp_path):
    out = tmp_path / "run"
    res = asap_dsl.train(tiny, steps=5_000_000, n_envs=2, out=out, settings=FAST, evaluate=False, time_limit=12,
                         search_iterations=1_000_000, demonstrations=0)  # the learner's and the search's shares alone
    record = RunDir(out).read_manifest()["policy_search"]
    assert res.status == "finished" and 1 <= record["iterations"] < 1_000_000
    assert res.steps < 5_000_000 and max(r["seconds"] for r in res.curves) < 0.75 * 12 + 3  # the learner's share
    assert 12 <= res.seconds < 12 + 4  # the search took the rest, and stopped on the clock


def test_an_arrival_within_its_step_is_where_the_robustness_crosses_zero():
    from asap_dsl.backends.rl.policy_search import crossing_time, rollout_batch
    from asap_dsl.rollout import ConstantController, Evaluator

    before, after = np.array([-1.0, -3.0, np.nan, 0.5]), np.ones(4)
    np.testing.assert_allclose(crossing_time(5.0, before, after), [4.5, 4.75, 5.0, 5.0])
    # At full speed the rail moves 0.2 a step and the goal's robustness is x - 0.8 below it:
    # linear in time, so the interpolated arrival is the exact one.
    prog = asap_dsl.loads(RAIL, "rail.asap")
    states = np.array([[0.01], [0.05], [-0.33]])
    _, arrival, crossing = rollout_batch(Evaluator(prog, None, states), ConstantController([1.0]), states, 0.9, None)
    exact = (0.8 - states[:, 0]) / 0.2
    np.testing.assert_allclose(crossing, exact, atol=1e-6)
    np.testing.assert_array_equal(arrival, np.ceil(exact))


def test_the_tolerances_objective_counts_an_arrival_sooner_within_the_step():
    from asap_dsl.backends.rl.policy_search import SearchSettings

    search, _ = _search(SearchSettings(population=2, batch=2, objective="tolerances"))
    crossing = np.array([4.2, np.inf, 4.6, np.inf])  # two candidates, two states each; one never arrives
    f = search.fitness(np.zeros(4), np.ceil(crossing), crossing)
    assert f[0] > f[1]
    within_5 = 1 / (1 + np.exp(-(5 - 4.2) / 0.5))  # the rail's tolerances are 20, 10 and 5 steps
    assert f[0] == pytest.approx((within_5 + 2 * 1.0) / 3 / 2, abs=1e-3)


def test_the_perturbations_shrink_until_they_cost_the_actor_little():
    from asap_dsl.backends.rl.policy_search import SCALES, SearchSettings, smoothing_scale

    tried = []
    assert smoothing_scale(lambda f: tried.append(f) or 10 * f, 0.5) == SCALES[3] and tried == list(SCALES)
    assert smoothing_scale(lambda f: 10 * f, 5.0) == SCALES[1]
    assert smoothing_scale(lambda f: 1.0, 0.0) == SCALES[-1]  # none small enough: the smallest
    # A climbed actor loses nothing to no perturbation and much to a large one; the search then
    # takes a smaller scale, and its first Adam step moves each parameter by learning rate x scale.
    search, _ = _search(SearchSettings(iterations=40, population=32, batch=64, sigma=0.1, learning_rate=0.03))
    state = search.start(0.0)
    for _ in range(40):
        state = search.iterate(state)
    assert search.smoothing_loss(state.theta, 0.0) == pytest.approx(0.0, abs=1e-12)
    assert search.smoothing_loss(state.theta, 3.0) > 0.1
    sharp, _ = _search(SearchSettings(population=32, batch=64, sigma=3.0, learning_rate=0.03, max_smoothing_loss=0.02))
    sharp.family.theta0 = state.theta
    begun = sharp.start(0.0)
    assert begun.scale < 1.0
    step = np.abs(sharp.iterate(begun).theta - state.theta)
    np.testing.assert_allclose(step.max(), 0.03 * begun.scale, rtol=1e-4)


def _constant_actor(family, action: float) -> np.ndarray:
    """Parameters under which the SAC actor's mean action is ``action`` everywhere: every weight
    zero, every bias of the action's size (the mean's, the log-std's) atanh(action)."""
    import jax
    from jax.flatten_util import ravel_pytree

    params = family._unravel(family.theta0)
    leaves = jax.tree_util.tree_map(lambda p: np.full(p.shape, np.arctanh(action), np.float32) if p.shape == (1,)
                                    else np.zeros(p.shape, np.float32), params)
    return np.asarray(ravel_pytree(leaves)[0], dtype=np.float64)


def test_the_gain_chosen_is_the_one_under_which_the_actor_arrives_soonest():
    from asap_dsl.backends.rl.policy_search import SearchSettings

    # The rail's goal lies right of most starts: a constant push of half the bound arrives sooner
    # at gain 2 (the bound) than at 1; no push arrives nowhere at any gain, and the smallest stays.
    search, _ = _search(SearchSettings(population=32, batch=64, action_gains=[2.0, 1.0]))
    assert search.settings.action_gains == (1.0, 2.0)
    push, still = _constant_actor(search.family, 0.5), _constant_actor(search.family, 0.0)
    assert search.choose_gain(push) == 2.0
    assert search.choose_gain(still) == 1.0
    search.family.theta0 = push
    state = search.start(0.0)
    assert state.gain == 2.0 and state.summary(0.0)["action_gain"] == 2.0
    row = search.validate(state)  # the iterations and validation act with it
    assert row["rates"][10] > 0.3
    alone, _ = _search(SearchSettings(population=32, batch=64))
    assert alone.choose_gain(push) == 1.0  # no candidates: gain 1
    search.family.gain = 1.0
    assert search.validate(state)["score"] == row["score"]  # validate sets the state's gain itself
    assert search.iterate(state).gain == 2.0  # and every iteration keeps it


def test_the_gain_is_chosen_again_for_the_parameters_kept():
    from asap_dsl.backends.rl.policy_search import SearchSettings

    search, _ = _search(SearchSettings(population=32, batch=64, action_gains=[1.0, 2.0], gain_for_kept=True))
    push = _constant_actor(search.family, 0.5)
    search.family.theta0 = _constant_actor(search.family, 0.0)  # the learner's actor: no gain helps it
    state = search.start(0.0)
    assert state.gain == 1.0
    # as if the search had kept the push at iteration 25 (and nothing since beat it)
    state.best_theta, state.best_iteration, state.best_score = push, 25, 10.0
    done = search.finish(state, to_beat=0.0)
    assert done.kept_gain == 2.0 and done.deployed_gain == 2.0 and done.kept()["gain"] == 2.0
    assert done.summary(0.0)["action_gain"] == 2.0 and done.summary(0.0)["search_gain"] == 1.0
    assert done.kept()["score"] == search._judge(push, 2.0)["score"]  # the record is what the model does
    assert done.summary(0.0)["score"] == done.kept()["score"]
    again = search.start(0.0)  # a gain that does not beat the learner's validation is not taken
    again.best_theta, again.best_iteration, again.best_score = push, 25, 10.0
    refused = search.finish(again, to_beat=1.0)
    assert refused.deployed_gain == 1.0 and refused.kept_row is None
