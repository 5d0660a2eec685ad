"""Docstring style as ament runs it (ament_pep257, the 'ament' convention)."""

from ament_pep257.main import main
from conftest import REPO
import pytest


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    rc = main(argv=[str(REPO / 'polyline_mapper'), str(REPO / 'test'), str(REPO / 'launch'),
                    str(REPO / 'benchmarks'),
                    str(REPO / 'tools')])
    assert rc == 0, 'Found code style errors / warnings'
