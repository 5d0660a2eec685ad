"""colcon: a workspace holding this repository builds both packages and the node's executable."""

import os
import pathlib
import subprocess
import sys

from conftest import REPO
import pytest

VENV = pathlib.Path(sys.prefix)
COLCON = pathlib.Path(sys.executable).parent / 'colcon'


@pytest.mark.slow
def test_colcon_build_installs_both_packages_and_a_runnable_node(tmp_path):
    if not COLCON.exists():
        pytest.skip('colcon is not installed: tools/dev.sh could not install '
                    'colcon-common-extensions (see <venv>/pip-colcon.log)')
    src = tmp_path / 'src'
    src.mkdir()
    (src / 'polyline_mapper').symlink_to(REPO)
    env = dict(os.environ, CMAKE_PREFIX_PATH=str(VENV), AMENT_PREFIX_PATH=str(VENV),
               PATH=f'{VENV / "bin"}:{os.environ["PATH"]}', COLCON_HOME=str(tmp_path / '.colcon'))
    before = set(_untracked())
    build = subprocess.run(
        [str(COLCON), 'build', '--base-paths', 'src/polyline_mapper',
         'src/polyline_mapper/polyline_mapper_msgs', '--event-handlers', 'console_cohesion-',
         '--cmake-args', '-DBUILD_TESTING=OFF'],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert build.returncode == 0, (build.stdout + build.stderr)[-4000:]
    assert 'Summary: 2 packages finished' in build.stdout, build.stdout[-2000:]
    install = tmp_path / 'install'
    exe = install / 'polyline_mapper' / 'lib' / 'polyline_mapper' / 'polyline_mapper_node'
    assert exe.is_file() and os.access(exe, os.X_OK)
    assert (install / 'polyline_mapper' / 'lib' / 'polyline_mapper' / 'polyline-mapper').is_file()
    for pkg in ('polyline_mapper', 'polyline_mapper_msgs'):
        marker = install / pkg / 'share' / 'ament_index' / 'resource_index' / 'packages' / pkg
        assert marker.is_file(), marker
    share = install / 'polyline_mapper' / 'share' / 'polyline_mapper'
    assert (share / 'config' / 'polyline_mapper.yaml').is_file()
    assert (share / 'launch' / 'polyline_mapper.launch.py').is_file()
    assert (install / 'polyline_mapper_msgs' / 'share' / 'polyline_mapper_msgs' / 'msg' /
            'PolylineMap.msg').is_file()
    # What `ros2 run polyline_mapper polyline_mapper_node` starts, from the sourced workspace:
    # it runs, imports everything, and refuses a bad parameter with one line.
    run = subprocess.run(
        ['bash', '-c', f'source {install}/setup.bash && {exe} --ros-args -p pose_source:=gps'],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 1, run.stdout + run.stderr
    assert 'pose_source must be one of tf, odom' in run.stderr
    assert set(_untracked()) == before, 'the build wrote into the repository'


def _untracked() -> list:
    """Return build artefacts (even git-ignored ones) in the repository."""
    out = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=all',
                          '--ignored'], cwd=REPO, capture_output=True, text=True)
    artefacts = ('build/', 'install/', 'log/', '.egg-info')
    return [ln for ln in out.stdout.splitlines()
            if '.venv/' not in ln and any(a in ln for a in artefacts)]
