"""Shared fixtures: seeded simulated data and the location of the shared real datasets."""

import os
import pathlib

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
DATASETS = pathlib.Path(os.environ.get('POLYLINE_MAPPER_DATASETS',
                                       REPO.parent / 'shared' / 'datasets'))


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
def office_fit(office_drive):
    """Fit the office drive once, shared by several tests."""
    from polyline_mapper.core import fit
    pts, hits = office_drive.points(with_hits=True)
    return pts, hits, fit(pts)
