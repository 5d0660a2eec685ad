"""Laser stamps off the pose data's clock: the lag estimate, its warning, ``scan_time_offset``."""

import dataclasses
import math
import re

import numpy as np
from polyline_mapper.formats.records import Scan
from polyline_mapper.poses import estimate_lag, lag_costs, LAG_GRID, stamp_lag
from polyline_mapper.recordings import (drive_messages, flat_records, make_drive, OdometryDrift,
                                        SIM_START)
from polyline_mapper.replay import replay_records
from polyline_mapper.session import LAG_EVERY, LAG_ROWS, SessionOptions
import pytest

DRIVE = 'sim:office,step=0.05,turn=0.1,moving_sensor=1'
"""0.5 m/s, turning in place at 1 rad/s, beams over the scan time (benchmarks/scan_clock.py)."""
SCANS = 300
"""The drive's first 30 s: two turns in place."""


@pytest.fixture(scope='module')
def drive():
    return make_drive(DRIVE, 1)


def _records(drive, lag: float, scans: int = SCANS) -> list:
    """Return the first ``scans`` scans with drifting odometry, stamped ``lag`` s late."""
    end = SIM_START + drive.stamps[scans]
    return [dataclasses.replace(r, stamp=r.stamp + lag) if isinstance(r, Scan) else r
            for r in flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0), odom_drift=1))
            if r.stamp < end]


def _run(drive, lag: float, pose_source: str = 'odom', offset: float = 0.0,
         scans: int = SCANS, reorder=lambda records: records):
    warned = []
    session = replay_records(reorder(_records(drive, lag, scans)), options=SessionOptions(
        pose_source=pose_source, scan_matching=True, keep_points=True,
        scan_time_offset=offset), warn=lambda cause, text: warned.append((cause, text)))
    return session, [text for cause, text in warned if cause == 'scan_clock']


def test_the_lag_is_read_off_the_drives_turns(drive):
    # The matched heading at a scan's stamp is the true one at the time it was taken; the
    # odometry's at its stamp runs `lag` ahead. Drifting odometry (noise 0.02 rad a step).
    t = SIM_START + drive.stamps
    true_yaw = np.unwrap(drive.poses[:, 2])
    odom_yaw = np.unwrap(OdometryDrift().apply(drive.poses, 1, stamps=drive.stamps)[:, 2])
    for lag in (-0.3, -0.1, 0.0, 0.05, 0.1, 0.3):
        est = stamp_lag(t, np.interp(t + lag, t, odom_yaw), true_yaw + 0.7)
        assert abs(est.lag - lag) <= 0.011, (lag, est)
        assert est.rms <= est.rms_zero and est.pairs >= 100
        if abs(lag) >= 0.05:
            assert est.rms_zero >= 1.5 * est.rms, (lag, est)
    # Only pairs whose odometry turn depends on the lag count: a straight stretch (no turn in
    # 4 s) has none, and no lag is found there.
    turning = np.abs(np.diff(true_yaw)) > 1e-9
    k = next(i for i in range(len(turning) - 40) if not turning[i:i + 40].any())
    straight = slice(k, k + 40)
    est = stamp_lag(t[straight], np.interp(t + 0.1, t, odom_yaw)[straight],
                    true_yaw[straight])
    assert est.pairs == 0 and math.isnan(est.lag), est


def test_the_odometry_is_never_read_past_the_rows_it_holds():
    # A noise-free series: turns of 3 s at 1 rad/s every 10 s, sampled at 10 Hz, the odometry
    # read `lag` later. Pairs whose shifted reads fell before the first row or after the newest
    # were scored against an odometry held still there, which pulled the estimate of 0.1 s to
    # 0.095 s with an RMS of 0.018 rad where the lag explains every pair exactly.
    t = 1000.0 + np.arange(600) * 0.1
    yaw = np.cumsum(np.where(t % 10.0 < 3.0, 0.1, 0.0))
    for lag in (-0.3, -0.1, 0.1, 0.3):
        given = np.interp(t + lag, t, yaw)
        est = stamp_lag(t[20:], given[20:], yaw[20:])
        assert est.lag == pytest.approx(lag, abs=1e-9) and est.rms < 1e-9, (lag, est)
        assert est.rms_zero > 0.05 and est.pairs >= 250, (lag, est)
        # The session's way, batches of LAG_EVERY over its last LAG_ROWS rows, each passing
        # on where it stopped: the same pairs and costs as one pass over every row.
        costs, pairs, since = np.zeros(len(LAG_GRID)), 0, -math.inf
        for end in range(LAG_EVERY, len(t) + 1, LAG_EVERY):
            rows = slice(max(end - LAG_ROWS, 0), end)
            c, p, since = lag_costs(t[rows], given[rows], yaw[rows], since)
            costs, pairs = costs + c, pairs + p
        whole, whole_pairs, upto = lag_costs(t, given, yaw)
        assert pairs == whole_pairs and since == upto == t[-1] + LAG_GRID[0]
        np.testing.assert_allclose(costs, whole, rtol=1e-9, atol=1e-12)
        assert estimate_lag(costs, pairs).lag == pytest.approx(lag, abs=1e-9)


@pytest.mark.parametrize('rate', [10.0, 100.0, 150.0])
def test_the_session_scores_every_pair_at_any_scan_rate(rate, monkeypatch):
    # The session's own batching (LAG_EVERY matched scans, the rows it keeps), fed noise-free
    # headings 0.1 s late, with no fading: the pairs and costs of one pass over all the rows,
    # and the lag. Rows capped at 300 lost pairs above 66 Hz and all from 100 Hz on (a helper
    # audit: 100 Hz, no estimate at all).
    import polyline_mapper.session as session_module
    monkeypatch.setattr(session_module, 'LAG_DECAY', 1.0)
    session = session_module.MappingSession(options=SessionOptions(pose_source='odom',
                                                                   scan_matching=True))
    t = 1000.0 + np.arange(int(60 * rate)) / rate
    yaw = np.minimum(t % 10.0, 3.0) + 3.0 * np.floor(t / 10.0)
    given = np.interp(t + 0.1, t, yaw)
    for stamp, g, y in zip(t, given, yaw):
        session._check_stamp_lag(stamp, np.array([0.0, 0.0, g]), np.array([0.0, 0.0, y]),
                                 'laser')
    assert len(session._turns) <= LAG_EVERY + 4.5 * rate           # bounded by time
    end = len(t) // LAG_EVERY * LAG_EVERY                           # the last batch's end
    costs, pairs, upto = lag_costs(t[:end], given[:end], yaw[:end])
    assert session._lag_since == upto and session._lag_pairs == pairs > 100 * rate / 10
    np.testing.assert_allclose(session._lag_costs, costs, rtol=1e-9, atol=1e-12)
    assert session.stamp_lag.lag == pytest.approx(0.1, abs=1e-9), session.stamp_lag


def _swapped(records: list, every: int) -> list:
    """Return ``records`` with two neighbouring scans swapped every ``every`` scans."""
    at = [i for i, r in enumerate(records) if isinstance(r, Scan)]
    out = list(records)
    for a, b in zip(at[every::every], at[every + 1::every]):
        out[a], out[b] = out[b], out[a]
    return out


@pytest.mark.parametrize('pose_source', ['odom', 'tf', 'odom, out of order'])
def test_scans_stamped_late_are_warned_with_the_offset_that_undoes_them(drive, pose_source):
    # A driver that stamps each scan when it sends it, 0.1 s after its first beam: one
    # warning, advising the offset within 20 ms, and not repeated while the lag stays. Scans
    # out of order (two swapped every 60) are left out of the estimate, which kept none
    # before (each one cleared its rows, as a clock jumping back does: a helper audit).
    if pose_source == 'odom, out of order':
        session, clock = _run(drive, 0.1, reorder=lambda records: _swapped(records, 60))
        assert session.used == SCANS
    else:
        session, clock = _run(drive, 0.1, pose_source)
    assert len(clock) == 1, clock
    advised = float(re.search(r'set scan_time_offset to (-?[0-9.]+)', clock[0]).group(1))
    assert abs(advised + 0.1) <= 0.02, clock[0]
    assert 'ms late' in clock[0]
    assert abs(session.stamp_lag.lag - 0.1) <= 0.02


def test_stamps_on_the_pose_datas_clock_are_not_warned_about(drive):
    session, clock = _run(drive, 0.0)
    assert clock == [] and session.stamp_lag is not None
    assert abs(session.stamp_lag.lag) < 0.03
    early, clock = _run(drive, -0.1)
    assert len(clock) == 1 and 'ms early' in clock[0], clock


def test_scan_time_offset_moves_every_stamp_before_it_is_posed(drive):
    # Stamped 0.1 s late and shifted back by the parameter: the map and trajectory of the
    # same scans stamped (t + 0.1) - 0.1 in the recording, bit for bit (not quite t in floats,
    # and the matching is chaotic in the last bits: against t it ends 3 cm apart), no warning.
    fixed, clock = _run(drive, 0.1, offset=-0.1, scans=150)
    assert clock == []
    recs = [dataclasses.replace(r, stamp=r.stamp - 0.1) if isinstance(r, Scan) else r
            for r in _records(drive, 0.1, 150)]
    assert sum(isinstance(r, Scan) for r in recs) == fixed.used == 150
    control = replay_records(recs, options=SessionOptions(
        pose_source='odom', scan_matching=True, keep_points=True))
    a, b = control.map_value(), fixed.map_value()
    assert np.array_equal(a.trajectory, b.trajectory)
    assert np.array_equal(a.segments, b.segments)


@pytest.mark.parametrize('bad', [math.nan, math.inf, 10.5, -11.0, True, '0.1'])
def test_a_scan_time_offset_that_cannot_be_right_is_refused(bad):
    with pytest.raises(ValueError, match='scan_time_offset'):
        SessionOptions(scan_time_offset=bad)


def test_the_node_parameter_and_the_replay_flag_reach_the_session(tmp_path, capsys):
    import json
    from polyline_mapper.cli import main
    from polyline_mapper.params import defaults, settings_from
    settings = settings_from(defaults() | {'scan_time_offset': -0.1})[0]
    assert settings.scan_time_offset == -0.1
    for bad in (11.0, 'late'):
        with pytest.raises(ValueError, match='scan_time_offset'):
            settings_from(defaults() | {'scan_time_offset': bad})
    pytest.importorskip('polyline_mapper_msgs.msg', reason='the messages are not built')
    from polyline_mapper.ros.node import session_options
    assert session_options(settings).scan_time_offset == -0.1
    # replay: the flag, and a parameter file's entry (the flag wins); the map records it
    path = tmp_path / 'robot.yaml'
    path.write_text('/**:\n  ros__parameters:\n    scan_time_offset: 0.25\n')
    runs = {}
    for name, argv in (('flag', ['--scan-time-offset', '0.5']), ('file', ['--config', str(path)]),
                       ('both', ['--config', str(path), '--scan-time-offset', '0.5'])):
        out = tmp_path / f'{name}.json'
        assert main(['replay', 'sim:hall', '-o', str(out), '-q', *argv]) == 0
        runs[name] = json.loads(out.read_text())
    for name, offset in (('flag', 0.5), ('file', 0.25), ('both', 0.5)):
        assert runs[name]['stats']['scan_time_offset'] == offset
        assert runs[name]['trajectory'][0][0] == pytest.approx(SIM_START + offset, abs=1e-9)
    # fit records it too; plot --points takes it from a map made so, and says so when another
    # is given (the scans are found on the trajectory by stamp: each would get another's pose)
    fit = tmp_path / 'fit.json'
    assert main(['fit', 'sim:hall', '-o', str(fit), '-q', '--scan-time-offset', '0.5']) == 0
    assert json.loads(fit.read_text())['stats']['scan_time_offset'] == 0.5
    capsys.readouterr()
    assert main(['plot', str(tmp_path / 'flag.json'), '--points', 'sim:hall', '-o',
                 str(tmp_path / 'p.png')]) == 0
    assert '--scan-time-offset 0.5' in capsys.readouterr().out
    assert main(['plot', str(tmp_path / 'flag.json'), '--points', 'sim:hall', '--pose-source',
                 'tf', '-o', str(tmp_path / 'p.png'), '-q']) == 0
    assert 'made with --scan-time-offset 0.5; registered with 0' in capsys.readouterr().err
    # a point file has no stamps to move
    pts = tmp_path / 'p.npy'
    np.save(pts, np.zeros((10, 2)))
    capsys.readouterr()
    assert main(['fit', str(pts), '-o', str(tmp_path / 'f.json'), '--scan-time-offset',
                 '0.1']) == 2
    assert '--scan-time-offset does not apply to a point file' in capsys.readouterr().err
