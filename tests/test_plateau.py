"""The learning-rate drop on a validation plateau: fires once, after ``patience`` validations in a
row without improvement; the model keeps the new rate through a save and a load."""

from __future__ import annotations

import pytest

import asap_dsl
from conftest import RAIL


def test_it_fires_once_after_patience_validations_without_improvement():
    from asap_dsl.backends.rl.plateau import PlateauDrop

    rule = PlateauDrop(0.1, 3)
    scores = [0.2, 0.5, 0.5, 0.4, 0.6, 0.6, 0.6, 0.6, 0.6, 0.6, 0.6]
    fired = [rule.seen(s, 1000 * i) for i, s in enumerate(scores)]
    # two without improvement (a tie is none), then 0.6 starts the count again; three more: fired, once
    assert fired.index(True) == 7 and fired.count(True) == 1 and rule.at_step == 7000
    again = PlateauDrop.from_dict(rule.to_dict())
    assert again == rule


def test_the_model_keeps_the_new_rate_through_save_and_load(tmp_path):
    from asap_dsl.backends.rl.config import resolve_config
    from asap_dsl.backends.rl.engines import get_engine
    from asap_dsl.backends.rl.plateau import set_learning_rate
    from asap_dsl.env import make_vec_env

    prog = asap_dsl.loads(RAIL, "rail.asap")
    cfg = resolve_config(prog, n_envs=2, settings={"net_arch": [8, 8]}, engine="sb3")
    engine = get_engine("sb3")
    model = engine.build("sac", make_vec_env(prog, num_envs=2, seed=0), cfg.hyper, 0)
    assert model.lr_schedule(1.0) == pytest.approx(1e-3)
    set_learning_rate(model, 1e-4)
    assert model.lr_schedule(1.0) == pytest.approx(1e-4) and model.lr_schedule(0.3) == pytest.approx(1e-4)
    model.save(str(tmp_path / "m.zip"))
    loaded = engine.load("sac", tmp_path / "m.zip")
    assert loaded.lr_schedule(1.0) == pytest.approx(1e-4)
