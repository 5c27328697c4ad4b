"""The ``Examples`` sections of the main public functions run as doctests (issue 27): what the documentation
shows is what the code does.
"""
from __future__ import annotations

import doctest
import importlib

import pytest

#: Modules whose docstrings carry runnable examples, and how many examples each has at least.
MODULES = {
    "gap_validation.core.config": 1,
    "gap_validation.core.models": 1,
    "gap_validation.core.margins": 1,
    "gap_validation.core.metrics": 1,
    "gap_validation.core.validator": 1,
    "gap_validation.core.wording": 1,
}


@pytest.mark.parametrize("module_name", sorted(MODULES))
def test_examples_run(module_name):
    module = importlib.import_module(module_name)
    tests = [t for t in doctest.DocTestFinder().find(module) if t.examples]
    assert len(tests) >= MODULES[module_name], f"{module_name}: fewer examples than {MODULES[module_name]}"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test)
    failed, attempted = runner.summarize(verbose=False)
    assert attempted and not failed, f"{module_name}: {failed} of {attempted} examples failed"
