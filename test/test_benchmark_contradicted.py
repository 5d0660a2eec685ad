"""benchmarks/common.py: the contradicted-share columns the benchmark tables report."""

import importlib
import sys

from conftest import REPO
import numpy as np
from polyline_mapper.core.freespace import judge
from polyline_mapper.recordings import drive_beams
from polyline_mapper.sim import LaserSpec, office_floor, simulate_drive

sys.path.insert(0, str(REPO / 'benchmarks'))
C = importlib.import_module('common')


def test_contradicted_gives_judges_share_and_finds_a_wall_across_the_corridor():
    world = office_floor()
    drive = simulate_drive(world, LaserSpec(beams=181, range_max=12.0, noise=0.01), step=0.5,
                           rng=3)
    points, origins = drive_beams(drive)
    phantom = np.array([[[12.0, 5.2], [12.0, 6.8]]])     # across the corridor (y 5 .. 7)
    segs = np.concatenate([world.walls, phantom])
    cols = C.contradicted(segs, points, origins)
    verdict = judge(segs, points, origins)
    assert cols['contradicted_pct'] == 100 * verdict.share
    assert cols['contradicted_segments'] == int(verdict.contradicted.sum())
    # the true walls stand where the beams end: only the phantom is contradicted
    assert verdict.contradicted.tolist() == [False] * len(world.walls) + [True]
    share = 1.6 / np.hypot(*(segs[:, 1] - segs[:, 0]).T).sum()
    assert np.isclose(cols['contradicted_pct'], 100 * share)
    assert C.contradicted(world.walls, points, origins) == {'contradicted_pct': 0.0,
                                                            'contradicted_segments': 0}


def test_notable_lines_lists_maps_above_two_percent_only():
    maps = [('a', 2.5, 3), ('b', 2.0, 1), ('c', None, None), ('d', 7.04, 1)]
    assert C.notable_lines(maps) == [
        '- a: 2.5 % of map length contradicted (3 segments).',
        '- d: 7.0 % of map length contradicted (1 segment).']
