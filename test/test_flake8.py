"""flake8 as ament runs it (ament_flake8's configuration: 99 columns, quotes, import order)."""

from ament_flake8.main import main_with_errors
from conftest import REPO
import pytest


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8():
    rc, errors = main_with_errors(argv=[str(REPO / 'polyline_mapper'), str(REPO / 'test'),
                                        str(REPO / 'launch'),
                                        str(REPO / 'benchmarks'), str(REPO / 'tools'),
                                        str(REPO / 'setup.py')])
    assert rc == 0, f'Found {len(errors)} code style errors / warnings:\n' + '\n'.join(errors)
