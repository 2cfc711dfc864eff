"""Long and deep specs: chains of any length compile and run (they are flat: sums, products,
`and`/`or` chains, lets and formulas defined through each other, in any declaration order);
real nesting past the limits is E001 at the place, in words."""

from __future__ import annotations

import numpy as np
import pytest

import asap_dsl
from asap_dsl.env import make_vec_env
from asap_dsl.limits import LIMITS
from asap_dsl.stl import ir
from conftest import BASE, position


def runs(src: str) -> asap_dsl.Program:
    """Loads, and every task's environment and offline evaluation give finite values."""
    prog = asap_dsl.loads(src)
    for name in prog.tasks:
        env = make_vec_env(prog, task=name, num_envs=2, seed=0)
        env.reset()
        for _ in range(3):
            _, rewards, _, _ = env.step(np.zeros((2, 1)))
            assert np.isfinite(rewards).all()
        rob = prog.task(name).spec.robustness(np.zeros((2, 4, 2)))
        assert rob.shape == (2, 4)
        assert prog.task(name).spec.text
    return prog


LONG = 3000


def test_a_sum_of_thousands_of_terms():
    prog = runs(BASE.replace("y' = u", "y' = u + " + " + ".join(["0.001 * x"] * LONG)))
    assert prog.system.kind == "ode"
    runs(BASE.replace("asap in goal", "asap in goal and " + " - ".join(["x"] * LONG) + " < 1e9"))
    runs(BASE.replace("y' = u", "y' = u * " + " * ".join(["1"] * LONG)))


def test_a_conjunction_and_a_disjunction_of_thousands_of_atoms():
    prog = runs(BASE.replace("asap in goal", "asap in goal and " + " and ".join(f"x > {-6 - i}" for i in range(LONG))))
    depth, size = ir.measure(prog.task("t").asap.ir)
    assert depth < 20 and size == 2 * (LONG + 1) - 1  # balanced: log2(n) deep
    runs(BASE.replace("asap in goal", "asap in goal or " + " or ".join(f"x > {6 + i}" for i in range(LONG))))


@pytest.mark.parametrize("order", [1, -1])
def test_a_chain_of_thousands_of_lets_in_either_order(order):
    lets = [f"  let l{i} = l{i - 1} + 0.001" for i in range(1, LONG)][::order]
    src = BASE.replace("dt = 0.1", "dt = 0.1\n  let l0 = x\n" + "\n".join(lets))
    runs(src.replace("asap in goal", f"asap in goal and l{LONG - 1} > -10").replace("y' = u", f"y' = u + 0 * l{LONG - 1}"))


def test_the_value_of_a_long_chain_is_the_value_as_written():
    prog = asap_dsl.loads(BASE.replace("asap in goal", "asap " + " and ".join(f"x > {i}" for i in range(200))))
    states = np.array([[250.0, 0.0], [50.0, 0.0], [-1.0, 0.0]])
    assert np.allclose(prog.task("t").asap.robustness(states[:, None, :])[:, 0], [250.0 - 199, 50.0 - 199, -1.0 - 199])


@pytest.mark.parametrize("nest", [
    lambda n: "y' = " + "(" * n + "u" + ")" * n,
    lambda n: "y' = " + "-" * n + "u",
    lambda n: "y' = " + "sin(" * n + "u" + ")" * n,
])
def test_nesting_past_the_limit_is_e001_at_the_place(nest):
    runs(BASE.replace("y' = u", nest(LIMITS.nesting - 2)))
    src = BASE.replace("y' = u", nest(LIMITS.nesting + 5))
    with pytest.raises(asap_dsl.SpecError) as err:
        asap_dsl.loads(src)
    d = err.value.diagnostics[0]
    assert d.code == "E001" and "nests more than 100 levels" in d.message
    assert d.line == position(src, "y' =")[0] and d.column > 10


def test_formula_nesting_is_e001_at_the_formula_and_not_below_the_limit():
    chain = "\n".join(f"formula f{i} = not f{i - 1}" if i else "formula f0 = x > 0" for i in range(150))
    runs(BASE.replace("task t {", chain + "\ntask t {").replace("asap in goal", "asap in goal and f149"))


def test_a_formula_that_doubles_at_each_step_is_e001_not_an_exponential_blowup():
    chain = "\n".join(f"formula f{i} = f{i - 1} or not f{i - 1}" if i else "formula f0 = x > 0" for i in range(40))
    src = BASE.replace("task t {", chain + "\ntask t {").replace("asap in goal", "asap in goal and f39")
    with pytest.raises(asap_dsl.SpecError) as err:
        asap_dsl.loads(src)
    d = err.value.diagnostics[0]
    assert d.code == "E001" and "expands to" in d.message and "f16" in d.message
    assert (d.line, d.column) == position(src, "f16 =")


def test_cycles_of_any_length_are_e120_once():
    chain = "\n".join(f"formula f{i} = f{(i + 1) % 2000} and x > 0" for i in range(2000))
    src = BASE.replace("task t {", chain + "\ntask t {").replace("asap in goal", "asap in goal and f0")
    with pytest.raises(asap_dsl.SpecError) as err:
        asap_dsl.loads(src)
    e120 = [d for d in err.value.diagnostics if d.code == "E120"]
    assert len(e120) == 1 and "defined in terms of itself" in e120[0].message


def test_resource_limits_are_raised_by_flags_and_in_python(capsys, tmp_path):
    from asap_dsl import cli
    from asap_dsl.limits import raised

    long = tmp_path / "long.asap"
    long.write_text(BASE.replace("deadline 30", "deadline 2000000").replace(
        "dt = 0.1", "dt = 0.1\n  integrator rk4(substeps = 5000)"))
    assert cli.main(["lint", str(long)]) == 1
    out = capsys.readouterr().out
    assert "more than 1,000,000" in out and "--max-deadline" in out
    assert "more than 1,000" in out and "--max-substeps" in out
    try:
        assert cli.main(["--max-deadline", "3000000", "--max-substeps", "5000", "lint", str(long)]) == 0
    finally:  # the flags set this process's limits: put them back for the other tests
        LIMITS.deadline_steps, LIMITS.substeps = 1_000_000, 1000
    with raised(deadline_steps=3_000_000, substeps=5000):
        asap_dsl.loads(long.read_text())
    assert LIMITS.deadline_steps == 1_000_000
    with pytest.raises(TypeError, match="unknown limit"):
        with raised(windows=3):
            pass
