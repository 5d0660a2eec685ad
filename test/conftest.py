"""
Shared fixtures: seeded simulated data and the location of the shared real datasets.

Also the rules that let the suite run on several pytest-xdist workers: each worker talks in
its own ROS domain, and a test marked ``dds`` (a node, player or recorder talking over DDS,
timing-sensitive) runs alone, the others side by side. ``tools/dev.sh test`` without arguments
runs the ``dds`` tests in a pytest run of their own, one after another, beside the others' run
on two workers at nice 19; the rules here order and lock a run that holds both kinds.
``rosnode`` refuses to start a node or a peer in a test that is not marked ``dds``.
"""

import contextlib
import os
import pathlib

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
DATASETS = pathlib.Path(os.environ.get('POLYLINE_MAPPER_DATASETS',
                                       REPO.parent / 'shared' / 'datasets'))
ALONE = 'POLYLINE_MAPPER_TEST_ALONE'
"""Set (to '1') while a test marked ``dds`` runs: what ``rosnode`` checks."""
_WORKER = os.environ.get('PYTEST_XDIST_WORKER', '')
if _WORKER.startswith('gw'):
    # Each worker its own ROS domain: a module-scoped node of one worker lives on between its
    # tests, and must not be seen by the other worker's tests (rclpy reads this at init).
    os.environ['ROS_DOMAIN_ID'] = str(
        (int(os.environ.get('ROS_DOMAIN_ID') or 0) + int(_WORKER[2:])) % 102)


def pytest_collection_modifyitems(config, items):
    """
    Run the ``dds`` tests last, in their order.

    Under pytest-xdist each of them waits for the other worker's running test to end, and the
    other worker idles while it runs: as one block at the end that is one hand-over, not one
    per test (on a 2-core VM the suite took 13.8 min so, 14.2 min with them interleaved).
    """
    items.sort(key=lambda item: item.get_closest_marker('dds') is not None)   # stable


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Run a ``dds`` test (its fixtures included) alone: no other worker runs a test meanwhile."""
    alone = item.get_closest_marker('dds') is not None
    workerinput = getattr(item.config, 'workerinput', None)
    with contextlib.ExitStack() as stack:
        if workerinput is not None:
            folder = pathlib.Path(item.config.option.basetemp).parent   # shared by the workers
            stack.enter_context(_turn(folder / 'polyline_mapper-tests', alone))
        if alone:
            os.environ[ALONE] = '1'
            stack.callback(os.environ.pop, ALONE, None)
        yield


@contextlib.contextmanager
def _turn(base: pathlib.Path, alone: bool):
    """
    Hold a readers-writer lock between the workers: exclusive if ``alone``, else shared.

    A gate lock, held by an exclusive taker until it has the main lock, keeps the shared takers
    (the other worker, test after test) from starving it.
    """
    import fcntl
    with open(f'{base}.gate', 'a') as gate, open(f'{base}.lock', 'a') as lock:
        fcntl.flock(gate, fcntl.LOCK_EX)
        try:
            fcntl.flock(lock, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        finally:
            fcntl.flock(gate, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def radish_log(name: str) -> pathlib.Path:
    """Path of a shared Radish log, or skip the test when the datasets are not here."""
    path = DATASETS / 'radish' / name
    if not path.is_file():
        pytest.skip(f'{path} not present (set POLYLINE_MAPPER_DATASETS to the datasets folder)')
    return path


def radish_head(name: str, scans: int, folder: pathlib.Path) -> pathlib.Path:
    """Write the first ``scans`` FLASER records of a shared Radish log as a log of their own."""
    import gzip
    lines, n = [], 0
    with gzip.open(radish_log(name), 'rt') as fh:
        for line in fh:
            n += line.startswith('FLASER')
            if n > scans:
                break
            lines.append(line)
    path = pathlib.Path(folder) / f'{pathlib.Path(name).name.split(".")[0]}-{scans}.log.gz'
    with gzip.open(path, 'wt') as fh:
        fh.writelines(lines)
    return path


def noisy_line(a, b, n, sigma, rng):
    """N points uniformly along segment ab with Gaussian normal noise sigma (m)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = rng.uniform(0, 1, n)
    d = b - a
    nrm = np.array([-d[1], d[0]]) / np.hypot(*d)
    return a + t[:, None] * d + rng.normal(0, sigma, n)[:, None] * nrm


def end_errors(found, a, b):
    """End-point error (m) of each found segment against segment ab, either way round."""
    from polyline_mapper.core.geometry import end_distance
    return end_distance(np.asarray(found, float), np.array([[a, b]], dtype=float))


@pytest.fixture(scope='session')
def office_drive():
    """Drive through the simulated office floor (1 cm noise, a scan every 0.4 m)."""
    from polyline_mapper.sim import LaserSpec, office_floor, simulate_drive
    return simulate_drive(office_floor(), LaserSpec(noise=0.01), step=0.4, rng=7)


@pytest.fixture(scope='session')
def office_map_file(tmp_path_factory):
    """
    Return the path of MAP.json of ``replay sim:office`` (true poses), made once per process.

    Shared by the modules that start from a saved office map (it was made in each of them):
    ``saved_office_map`` gives each its own copy.
    """
    from polyline_mapper.cli import main
    path = tmp_path_factory.mktemp('office_map') / 'office.json'
    assert main(['replay', 'sim:office', '-o', str(path), '-q']) == 0
    return path


def saved_office_map(office_map_file, folder) -> pathlib.Path:
    """Copy ``office_map_file`` into ``folder``; return the copy's path (office.json)."""
    import shutil
    return pathlib.Path(shutil.copyfile(office_map_file, pathlib.Path(folder) / 'office.json'))


@pytest.fixture(scope='session')
def office_fit(office_drive):
    """Fit the office drive once, shared by several tests."""
    from polyline_mapper.core import fit
    pts, hits = office_drive.points(with_hits=True)
    return pts, hits, fit(pts)
