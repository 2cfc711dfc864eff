"""The plateau rule: a run ends, as finished, once validation has stopped improving."""

from __future__ import annotations

from dataclasses import replace

import pytest

from asap_dsl.backends.rl import presets
from asap_dsl.backends.rl.validation import PLATEAU_GAIN, plateau_reached


def _rows(*pairs):
    return [{"steps": s, "score": v} for s, v in pairs]


def test_a_run_ends_once_it_has_trained_as_long_again_as_its_progress_took():
    rows = _rows((100, 0.2), (200, 0.6), (300, 0.8), (400, 0.8 + PLATEAU_GAIN / 2))
    assert not plateau_reached(rows[:2], 200, 0.5)        # fewer than three validations: never
    assert not plateau_reached(rows, 400, 0.5)            # progress at 300 of 400: the last half moved it
    rows += _rows((500, 0.79), (600, 0.805))
    assert plateau_reached(rows, 600, 0.5)                # within the gain of the best since 300: 300 <= 600 / 2
    # a real gain late restarts the count; noise under the gain does not
    assert not plateau_reached(rows + _rows((700, 0.8 + 2 * PLATEAU_GAIN)), 700, 0.5)
    assert plateau_reached(_rows((100, 0.0), (200, 0.0), (300, 0.0)), 300, 0.5)  # nothing learnt: it ends too
    assert not plateau_reached(rows, 600, 0.6)            # a larger share waits longer


def test_the_run_ends_on_the_plateau_as_finished_and_says_so(tiny, tmp_path, monkeypatch):
    from asap_dsl.backends.rl.training import train

    monkeypatch.setitem(presets.PRESETS, "default", replace(presets.DEFAULT, plateau=0.5, demonstrations=0,
                                                             late_demonstrations=0))
    told = []

    class Progress:  # the display's protocol; the notes kept
        def start(self, *a): pass
        def advance(self, *a): pass
        def validated(self, *a): pass
        def finish(self): pass
        def note(self, line): told.append(line)

    res = train(str(tiny), "go", steps=80_000, seed=0, out=tmp_path / "run", eval_episodes=50,
                progress=Progress())
    assert res.status == "finished" and res.config.plateau == 0.5
    # the rail's validation stops improving after 20,000-30,000 steps (measured): the run stops
    # once it has trained as long again, long before its 80,000
    assert res.steps < 80_000, res.curves
    assert plateau_reached(res.curves, res.steps, 0.5)
    earlier = [plateau_reached(res.curves[:i + 1], r["steps"], 0.5) for i, r in enumerate(res.curves[:-1])]
    assert not any(earlier)  # it ended at the first validation that found the plateau
    assert any(f"the run ends at step {res.steps:,} of 80,000" in line for line in told), told
    assert res.evaluation is not None
    # complete at fewer steps: the manifest says where, and a resume trains nothing more
    from asap_dsl.runs import RunDir

    m = RunDir(tmp_path / "run").read_manifest()
    assert m["status"] == "finished" and m["plateau_step"] == res.steps == m["steps_done"]
    again = train(str(tiny), "go", steps=80_000, seed=0, out=tmp_path / "run", resume=True, evaluate=False)
    assert again.steps == res.steps and RunDir(tmp_path / "run").read_manifest()["steps_done"] == res.steps


def test_no_run_ends_on_the_plateau_before_its_share_of_the_steps(tiny, tmp_path, monkeypatch):
    """A learner stuck for a while may still break out (the swimmer did): the rule waits."""
    from asap_dsl.backends.rl.training import train

    monkeypatch.setitem(presets.PRESETS, "default", replace(presets.DEFAULT, plateau=0.5, plateau_after=0.9,
                                                             demonstrations=0, late_demonstrations=0))
    res = train(str(tiny), "go", steps=30_000, seed=0, out=tmp_path / "run", evaluate=False)
    assert res.status == "finished" and res.config.plateau_after == 0.9
    assert res.steps >= 27_000, res.curves
