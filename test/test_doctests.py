"""The docstring examples of the package (all but its rclpy shell, ``ros``) run as tests."""

import doctest
import importlib
import pkgutil

import polyline_mapper
import polyline_mapper.core
import pytest

# Every module outside ``polyline_mapper.ros``: until 2026-12-02 only the core's ran, and two
# examples elsewhere had gone wrong (an API audit: poses.TransformBuffer2D showed no output
# for a lookup, formats.bag.BagReader opened a bag that does not exist).
MODULES = sorted(
    m.name for m in pkgutil.walk_packages(polyline_mapper.__path__, 'polyline_mapper.')
    if not m.name.startswith('polyline_mapper.ros'))


@pytest.mark.parametrize('name', MODULES)
def test_docstring_examples_of_the_package_run(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0, f'{result.failed} of {result.attempted} examples failed'


def test_the_public_entry_points_have_examples():
    finder = doctest.DocTestFinder()
    core = polyline_mapper.core
    for obj in (core.fit, core.IncrementalMapper, core.assemble_polylines,
                core.polylines.map_geometry):
        assert any(t.examples for t in finder.find(obj)), obj.__name__
