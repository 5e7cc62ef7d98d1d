# SPDX-License-Identifier: Apache-2.0
"""The runnable examples in the docstrings of the stages' entry points run and show what they say.

Each example works on a small synthetic input (a drawn thread mask, a projected 3D curve, a
drawn thread image), so that the documented calls and outputs cannot drift from the code.
"""

from __future__ import annotations

import doctest
import importlib

import pytest

ENTRY_POINTS = (
    ("suture_ordering.core", "order_stereo"),
    ("suture_reconstruction.core", "reconstruct"),
    ("suture_segmentation.core", "Segmenter"),
)


@pytest.mark.parametrize(("module_name", "name"), ENTRY_POINTS)
def test_docstring_example_runs(module_name, name):
    module = importlib.import_module(module_name)
    (test,) = [t for t in doctest.DocTestFinder().find(module) if t.name == f"{module_name}.{name}"]
    assert test.examples, f"{module_name}.{name} has no example in its docstring"
    runner = doctest.DocTestRunner()
    runner.run(test)
    assert runner.summarize(verbose=False).failed == 0  # the failing lines are printed above
