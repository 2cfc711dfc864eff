"""Reorganising the code changes no output: lint, show and oracle on every spec and example, and the
README's broken.asap, byte for byte against the outputs recorded by tests/golden.py."""

from __future__ import annotations

import pytest

import golden


@pytest.mark.parametrize("argv", golden.commands(), ids=golden.name)
def test_output_is_the_recorded_one(argv):
    recorded = (golden.GOLDEN / golden.name(argv)).read_text(encoding="utf-8")
    assert golden.run(argv) == recorded
