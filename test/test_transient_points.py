"""benchmarks/transient.py: points that later beams see through are transient, walls are not."""

import importlib
import sys

from conftest import REPO
import numpy as np
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper
from polyline_mapper.sim import LaserSpec, office_dynamic, simulate_drive
import pytest

sys.path.insert(0, str(REPO / 'benchmarks'))
T = importlib.import_module('transient')

EVERY = 9
"""Classify every 9th point of the drive (the beams are all of them): a few seconds."""


@pytest.fixture(scope='module')
def scene():
    """Map the dynamic office (seeded) by default; count every 9th point's beams."""
    drive = simulate_drive(office_dynamic(), LaserSpec(noise=0.01), rng=1)
    mapper = IncrementalMapper(IncrementalConfig())
    angles = drive.spec.angles()
    for r, p in zip(drive.ranges, drive.poses):
        mapper.update_scan(r, angles, p, drive.spec.range_min, drive.spec.range_max)
    pts, hits = drive.points(with_hits=True)
    org = drive.origins()
    sub = np.arange(0, len(pts), EVERY)
    counts = T.transient_counts(pts, org, sub, mapper.polylines().segments)
    return drive, pts, org, hits, sub, mapper.polylines().segments, counts


def groups(drive, pts, hits, sub):
    """Masks over ``sub``: static walls, then each dynamic object's points off the walls."""
    world = drive.world
    h = hits[sub]
    off_walls = world.distance(pts[sub]) > 0.15
    static = h < len(world.walls) + len(world.arcs)
    return static, {o.name: np.isin(h, i) & off_walls
                    for o, i in zip(world.dynamic, world.dynamic_ids())}


def test_people_door_and_box_are_transient_walls_are_not(scene):
    drive, pts, _, hits, sub, _, counts = scene
    static, moved = groups(drive, pts, hits, sub)
    transient = T.is_transient(counts)
    assert static.sum() > 20000
    # Static walls: later beams end on them; a few points within 5 cm of a door jamb or on the
    # pillar's rim are seen past.
    assert transient[static].mean() <= 0.002, transient[static].mean()
    for name in ('door', 'corridor walker'):
        assert moved[name].sum() > 100
        assert transient[moved[name]].mean() >= 0.95, (name, transient[moved[name]].mean())
    # The corridor walker crosses the box's place after it is carried away: some of its beams
    # end where the box's south face was.
    assert transient[moved['box']].mean() >= 0.7, transient[moved['box']].mean()


def test_time_runs_forward(scene):
    # The same drive played backwards: the door is open first and shut at the end, the box
    # appears, so their points are seen through only by EARLIER beams, never transient.
    drive, pts, org, hits, sub, segs, _ = scene
    starts, stops = T.run_bounds(org)
    order = np.concatenate([np.arange(a, b) for a, b in zip(starts[::-1], stops[::-1])])
    where = np.empty_like(order)
    where[order] = np.arange(order.size)
    counts = T.transient_counts(pts[order], org[order], np.sort(where[sub]), segs)
    back = counts[np.argsort(np.argsort(where[sub]))]
    _, moved = groups(drive, pts, hits, sub)
    for name in ('door', 'box'):
        m = moved[name]
        assert not T.is_transient(back[m]).any(), name
        earlier = (back[m, 2] >= 1) & (back[m, 2] > back[m, 3])
        assert earlier.mean() >= 0.7, (name, earlier.mean())


def test_no_points_no_counts():
    out = T.transient_counts(np.zeros((0, 2)), np.zeros((0, 2)))
    assert out.shape == (0, 4)
    pts = np.array([[1.0, 0.0], [1.0, 0.1], [1.0, 0.2]])
    out = T.transient_counts(pts, np.zeros((3, 2)), [1])
    assert out.tolist() == [[0, 0, 0, 0]]       # one scan: no other beams
