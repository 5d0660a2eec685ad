"""Odometry much slower than the scans: warned once (``odom_rate``), never at usual rates."""

import dataclasses

import numpy as np
from polyline_mapper.formats.records import Odometry, Transform
from polyline_mapper.recordings import drive_messages, make_drive, SIM_START
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions
import pytest

DRIVE = 'sim:office,step=0.05,turn=0.1,moving_sensor=1'
"""10 Hz scans, 0.5 m/s, turning in place at 1 rad/s (benchmarks/odom_rate.py)."""


@pytest.fixture(scope='module')
def records():
    """Return the drive's first 200 scans with drifting odometry (seed 1), one message a scan."""
    drive = make_drive(DRIVE, 1)
    end = SIM_START + drive.stamps[200]
    out = []
    for _, _, rec in drive_messages(drive, mount=(0.0, 0.0, 0.0), odom_drift=1):
        out.extend(r for r in (rec if isinstance(rec, list) else [rec]) if r.stamp < end)
    return out


def _thinned(records: list, every: int) -> list:
    """Keep one odometry message (and odom -> base_link transform) in ``every``."""
    seen = {Odometry: 0, Transform: 0}
    out = []
    for r in records:
        if isinstance(r, Odometry) or (isinstance(r, Transform) and not r.static):
            seen[type(r)] += 1
            if (seen[type(r)] - 1) % every:
                continue
        out.append(r)
    return out


def _warned(records: list, pose_source: str, scan_matching: bool) -> list:
    warned = []
    session = replay_records(records, options=SessionOptions(
        pose_source=pose_source, scan_matching=scan_matching),
        warn=lambda cause, text: warned.append((cause, text)))
    scans = sum(not isinstance(r, (Odometry, Transform)) for r in records)
    assert session.used >= 0.95 * scans, (session.used, scans)
    return [text for cause, text in warned if cause == 'odom_rate']


@pytest.mark.parametrize('pose_source, scan_matching', [('odom', True), ('tf', False)])
def test_odometry_at_1_hz_under_10_hz_scans_is_warned_once(records, pose_source,
                                                           scan_matching):
    # Interpolated across a second, the odometry spreads each change of the turn rate over
    # it: walls F1 0.84 with matching on the whole drive, against 1.00 at 10 Hz
    # (benchmarks/odom_rate.py). One warning, naming the rate and the edge.
    said = _warned(_thinned(records, 10), pose_source, scan_matching)
    assert len(said) == 1, said
    assert 'every 1000 ms (1.0 Hz), 10 x the scans' in said[0]
    edge = 'the odometry' if pose_source == 'odom' else 'the transform odom -> base_link'
    assert said[0].startswith(edge), said[0]


def test_odometry_at_the_scan_rate_or_at_5_hz_is_not_warned_about(records):
    # One message per scan (the simulator, converted CARMEN logs), and 5 Hz, which maps as
    # 10 Hz does (F1 1.00): silent. Scans stamped out of order change nothing.
    assert _warned(records, 'odom', True) == []
    assert _warned(_thinned(records, 2), 'tf', False) == []
    scans = [i for i, r in enumerate(records) if not isinstance(r, (Odometry, Transform))]
    swapped = list(records)
    for a in scans[20:200:30]:
        swapped[a] = dataclasses.replace(records[a], stamp=records[a].stamp + 0.15)
    assert _warned(swapped, 'odom', False) == []


def test_the_warning_needs_odometry_slower_than_the_scans_not_only_slow(records):
    # Odometry at 2.5 Hz under scans at 2.5 Hz (one of each per 0.4 s): each scan has its
    # own odometry message, nothing to interpolate across: silent.
    scans = [r for r in records if not isinstance(r, (Odometry, Transform))]
    keep = {r.stamp for r in scans[::4]}
    sparse = [r for r in records if r.stamp in keep or getattr(r, 'static', False)]
    assert np.isclose(np.median(np.diff(sorted(keep))), 0.4)
    assert _warned(sparse, 'odom', False) == []
