"""The docstring examples of the numeric core run as tests."""

import doctest
import importlib
import pkgutil

import polyline_mapper.core
import pytest

MODULES = sorted(m.name for m in pkgutil.iter_modules(polyline_mapper.core.__path__))


@pytest.mark.parametrize('name', MODULES)
def test_docstring_examples_of_the_core_run(name):
    module = importlib.import_module(f'polyline_mapper.core.{name}')
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0, f'{result.failed} of {result.attempted} examples failed'


def test_the_public_entry_points_have_examples():
    finder = doctest.DocTestFinder()
    core = polyline_mapper.core
    for obj in (core.fit, core.IncrementalMapper, core.assemble_polylines,
                core.polylines.map_geometry):
        assert any(t.examples for t in finder.find(obj)), obj.__name__
