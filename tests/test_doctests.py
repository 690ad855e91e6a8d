"""Every example in the package's docstrings runs, and shows what it says it shows.

The modules are found by their source (each one that holds a ``>>>``), so an example added to
any module is run here without a list to keep.
"""

import doctest
import importlib
import importlib.util
import pkgutil

import pytest

import piezopreload


def _modules_with_examples():
    names = []
    for info in pkgutil.walk_packages(piezopreload.__path__, "piezopreload."):
        spec = importlib.util.find_spec(info.name)
        if spec is None or not spec.origin or not spec.origin.endswith(".py"):
            continue
        with open(spec.origin, encoding="utf-8") as f:
            if ">>>" in f.read():
                names.append(info.name)
    return sorted(names)


MODULES = _modules_with_examples()


def test_the_examples_are_found():
    """The search finds the modules known to hold examples (a search that finds nothing would pass every run)."""
    assert {"piezopreload.core.config", "piezopreload.models.ops", "piezopreload.core.records",
            "piezopreload.core.artifacts"} <= set(MODULES), MODULES


@pytest.mark.parametrize("name", MODULES)
def test_the_examples_of(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS, report=False, verbose=False)
    assert result.attempted > 0, f"{name} holds '>>>' but doctest ran no example of it"
    assert result.failed == 0, f"{result.failed} of the {result.attempted} examples of {name} failed (run " \
                               f"'python -m doctest -v' on its file to see which)"
