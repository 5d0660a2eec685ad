"""
Imperfect poses (issue 19): drifting wheel odometry, a moving sensor, scans without poses.

Simulated drives (``sim:`` options) with odometry that drifts like wheel odometry
(``OdometryDrift``, seeded; no map frame) and a lidar whose beams are taken over the scan time,
replayed through the mapping session with scan matching, motion compensation and the
scan-only pose source; scored against the simulator's true poses and walls.
"""

import dataclasses
import functools
import importlib
import math
import sys
import time

from conftest import REPO
import numpy as np
from polyline_mapper.core.geometry import se2_compose, se2_inverse
from polyline_mapper.core.incremental import IncrementalConfig
from polyline_mapper.core.metrics import scan_consistency, trajectory_error
from polyline_mapper.core.register import transform
from polyline_mapper.formats.records import Odometry, Scan, Transform
from polyline_mapper.recordings import (drive_messages, flat_records, make_drive, OdometryDrift,
                                        open_recording, SIM_MOUNT, sim_options)
from polyline_mapper.replay import replay_records
from polyline_mapper.scan import scan_to_points
from polyline_mapper.session import MappingSession, ODOM_JUMP, SessionOptions
from polyline_mapper.sim import corridor_loop, LaserSpec, office_floor, simulate_drive
import pytest

sys.path.insert(0, str(REPO / 'benchmarks'))
B = importlib.import_module('baselines')


def records(drive, drift=None, compensate=True, scans_only=False):
    """Return a drive's records, the laser on base_link (so rows compare with its poses)."""
    out = []
    for r in flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0), odom_drift=drift)):
        if isinstance(r, Scan) and not compensate:
            r = dataclasses.replace(r, time_increment=0.0)
        if not scans_only or isinstance(r, Scan):
            out.append(r)
    return out


def score(drive, session, origin=None):
    """Trajectory errors (per scan: metres, radians) and the map's scores against the truth."""
    value = session.map_value()
    traj = value.trajectory.copy()
    points, segments = session.points(), value.segments
    if origin is not None:              # scan mode: the map frame is the first scan's laser
        traj[:, 1:] = se2_compose(origin, traj[:, 1:])
        points = transform(points, origin)
        segments = transform(segments.reshape(-1, 2), origin).reshape(-1, 2, 2)
    i = np.searchsorted(1000.0 + drive.stamps, traj[:, 0] - 1e-6)
    err = np.hypot(*(traj[:, 1:3] - drive.poses[i, :2]).T)
    yaw = np.abs(np.angle(np.exp(1j * (traj[:, 3] - drive.poses[i, 2]))))
    world = drive.world
    walls = B.wall_scores(segments, world.walls, world.distance, points=drive.points())
    return {'rms': float(np.sqrt(np.mean(err ** 2))), 'err': err, 'yaw': yaw, 'index': i,
            'mean_distance': float(world.distance(points).mean()), 'walls': walls,
            'used': session.used}


def replay(spec, seed=1, drift=None, compensate=True, pose_source='tf', matching=True):
    drive = make_drive(spec, seed)
    scans_only = pose_source == 'scan'
    session = replay_records(records(drive, drift, compensate, scans_only),
                             options=SessionOptions(pose_source=pose_source,
                                                    scan_matching=matching, keep_points=True))
    return drive, score(drive, session, drive.poses[0] if scans_only else None)


# -- the simulator ------------------------------------------------------------------------------
def test_sim_options_give_drifting_odometry_and_a_moving_sensor():
    with open_recording('sim:hall,odom_drift=3,moving_sensor=1,step=0.5', seed=2) as rec:
        drive = rec.drive
        recs = list(rec.records())
        assert 'odometry drifting (seed 3), no map frame, moving sensor' in rec.description
    scans = [r for r in recs if isinstance(r, Scan)]
    odom = np.array([[o.translation[0], o.translation[1]] for o in recs
                     if isinstance(o, Odometry)])
    assert len(scans) == len(drive.poses) == len(odom)
    # no map frame; odometry starts true and drifts (reproducibly: seeded)
    assert not any(r.parent == 'map' for r in recs if isinstance(r, Transform))
    base = drive.poses[:, :2] - 0.2 * np.column_stack([np.cos(drive.poses[:, 2]),
                                                       np.sin(drive.poses[:, 2])])
    drift = np.hypot(*(odom - base).T)
    assert drift[0] < 1e-9 and 0.05 < drift.max() < 5.0
    with open_recording('sim:hall,odom_drift=3,moving_sensor=1,step=0.5', seed=2) as again:
        assert np.array_equal(odom, [o.translation[:2] for o in again.records()
                                     if isinstance(o, Odometry)])
    # a lidar spinning once per scan (10 Hz): beams 1/3600 s apart over 541 of 720 steps
    ti = scans[0].time_increment
    assert ti == pytest.approx(0.1 / 720, rel=1e-6) and scans[0].scan_time == pytest.approx(0.1)
    assert drive.time_increment == ti and all(s.time_increment == ti for s in scans)
    # each beam from where the laser was at its own time: the first beam from the scan's
    # pose, the last one 0.075 s later, a quarter of a step further
    last = drive.beam_poses(3)[-1]
    expected = drive.poses[3] + 0.75 * (drive.poses[4] - drive.poses[3])
    np.testing.assert_allclose(last, expected, atol=1e-9)
    np.testing.assert_allclose(drive.beam_poses(3)[0], drive.poses[3], atol=1e-12)


def test_default_drives_have_no_time_increment_and_options_are_checked():
    with open_recording('sim:hall', seed=2) as rec:
        scans = [r for r in rec.records() if isinstance(r, Scan)]
        assert all(s.time_increment == 0.0 and s.scan_time == 0.0 for s in scans)
        assert any(r.parent == 'map' for r in rec.records() if isinstance(r, Transform))
    assert sim_options('sim:office,turn=0.2,step=0.1,rate=20') == (
        'office', {'turn': 0.2, 'step': 0.1, 'rate': 20.0})
    for bad, text in (('sim:office,drift=1', "unknown simulated drive option 'drift=1'"),
                      ('sim:office,moving_sensor=yes', 'moving_sensor must be 0 or 1'),
                      ('sim:office,step=0', 'step must be a number of metres in [0.01, 10]'),
                      ('sim:office,turn=nan', 'turn must be a number of radians >= 0.01'),
                      ('sim:office,odom_drift=-1', 'odom_drift must be an integer seed')):
        with pytest.raises(ValueError) as info:
            make_drive(bad)
        assert text in str(info.value) and '\n' not in str(info.value)


def test_turning_in_place_keeps_the_position_and_bounds_the_turn():
    drive = make_drive('sim:office,turn=0.2')
    step = np.diff(drive.poses, axis=0)
    turn = np.abs(np.angle(np.exp(1j * step[:, 2])))
    moved = np.hypot(step[:, 0], step[:, 1])
    assert turn.max() <= 0.2 + 1e-9
    assert np.all(moved[turn > 1e-9] < 1e-12)          # it turns standing still
    assert len(drive.poses) > len(make_drive('sim:office').poses)


# -- motion compensation -------------------------------------------------------------------------
def test_motion_compensation_places_each_beam_where_the_laser_was():
    # Poses true (TF), no scan matching: a moving sensor smears the walls; with each beam
    # placed at the pose of its own time, they are as thin as a still sensor's.
    drive = make_drive('sim:hall,moving_sensor=1', 4)
    out = {}
    for compensate in (True, False):
        session = replay_records(records(drive, compensate=compensate),
                                 options=SessionOptions(keep_points=True))
        out[compensate] = score(drive, session)['mean_distance']
    assert out[True] < 0.012 and out[True] < 0.4 * out[False], out


@pytest.mark.parametrize('ros1', [False, True])
def test_a_moving_sensor_survives_a_bag_and_is_compensated_from_it(tmp_path, ros1):
    from bag_helpers import write_bag, write_ros1_bag
    from polyline_mapper.replay import run_replay
    drive = make_drive('sim:hall,moving_sensor=1', 4)
    messages = [(topic, rec, t) for t, topic, rec in drive_messages(drive)]
    path = (write_ros1_bag(tmp_path / 'moving.bag', messages) if ros1
            else write_bag(tmp_path / 'moving', messages))
    with open_recording(path) as rec:
        scans = [r for r in rec.records() if isinstance(r, Scan)]
    assert len(scans) == len(drive.poses)
    assert all(s.time_increment == np.float32(drive.time_increment)
               and s.scan_time == np.float32(0.1) for s in scans)
    res = run_replay(path)
    assert res.used == len(drive.poses)
    assert drive.world.distance(res.points).mean() < 0.012


def test_a_scan_waits_for_the_pose_of_its_last_beam():
    drive = make_drive('sim:hall,moving_sensor=1', 4)
    recs = records(drive)
    session = MappingSession(options=SessionOptions(keep_points=True))
    first = next(i for i, r in enumerate(recs) if isinstance(r, Scan))
    for r in recs[:first + 1]:
        session.add(r)
    session.step()
    assert session.used == 0 and session.skipped == {}      # its last beam: 0.075 s later
    nxt = next(i for i, r in enumerate(recs) if i > first and isinstance(r, Scan))
    for r in recs[first + 1:nxt]:
        session.add(r)
    session.step()
    session.flush(final=False)
    assert session.used == 1


def test_a_bad_time_increment_is_ignored_with_a_warning():
    drive = make_drive('sim:hall', 4)
    warned = []
    session = MappingSession(options=SessionOptions(keep_points=True),
                             warn=lambda cause, text: warned.append((cause, text)))
    for r in records(drive)[:30]:
        if isinstance(r, Scan):
            r = dataclasses.replace(r, time_increment=float('nan') if r.stamp < 1000.35
                                    else 0.01)
        session.add(r)
        session.step()
    session.flush()
    assert session.used > 5 and session.skipped == {}
    assert warned and {c for c, _ in warned} == {'time_increment'}
    assert all('ignored (no motion compensation)' in t for _, t in warned)


# -- drifting odometry, a moving sensor, scan matching -------------------------------------------
@pytest.fixture(scope='module')
def office_drifting():
    """Replay the office drive turning in place, odometry drifting (seed 1), a still sensor."""
    return replay('sim:office,turn=0.2', drift=1)


def test_drifting_odometry_is_corrected_by_scan_matching(office_drifting):
    drive, s = office_drifting
    assert s['rms'] <= 0.05 and s['walls']['f1'] == 1.0, (s['rms'], s['walls'])
    _, raw = replay('sim:office,turn=0.2', drift=1, matching=False)
    assert raw['rms'] > 10 * s['rms'] and raw['walls']['f1'] < 0.5


def test_a_rotation_in_place_and_a_doorway_passage_hold(office_drifting):
    drive, s = office_drifting
    step = np.diff(drive.poses, axis=0)
    turning = np.flatnonzero(np.abs(np.angle(np.exp(1j * step[:, 2]))) > 1e-9) + 1
    turning = np.isin(s['index'], turning)
    assert turning.sum() > 100
    assert s['err'][turning].max() < 0.05 and s['yaw'][turning].max() < 0.01
    # the door of the bottom-left room: corridor wall y = 5 open for x in 2.5 .. 3.5
    p = drive.poses[s['index']]
    door = (np.abs(p[:, 0] - 3.0) < 0.3) & (np.abs(p[:, 1] - 5.0) < 0.75)
    assert door.sum() >= 6
    assert s['err'][door].max() < 0.05 and s['yaw'][door].max() < 0.01


def test_a_laser_that_sees_nothing_keeps_the_pose_going_and_the_map_alone():
    # Session 67: mapping with scan matching from odometry, a scan with no return on any beam
    # was skipped when it came, so nothing was published (no pose, no map -> odom) while the
    # laser saw nothing, and a planner's transform lookups failed once the last transform was
    # older than their tolerance. AMCL republishes map -> odom with every scan. Now such a scan
    # is posed as a scan not matched (the odometry's pose, the covariance growing), and it
    # maps nothing: the map is the one of the same drive without those scans.
    drive = make_drive('sim:office', 1)
    blinded, dropped, n = [], [], 0
    for r in records(drive, drift=1):
        if isinstance(r, Scan):
            n += 1
            if 100 < n <= 130:
                blinded.append(dataclasses.replace(r, ranges=np.full(len(r.ranges), np.inf,
                                                                     np.float32)))
                continue
        blinded.append(r)
        dropped.append(r)
    rows = []

    def keep(session):
        loc = session.localization
        if loc is not None and (not rows or rows[-1][0] != loc.stamp):
            rows.append((loc.stamp, loc.matched, loc.covariance[0, 0], *loc.pose[:2]))
    options = SessionOptions(pose_source='odom', scan_matching=True)
    seen = replay_records(blinded, options=options, progress=keep)
    assert seen.skipped == {'bad scan: no_valid_ranges': 30}
    assert np.array_equal(seen.map_value().segments,
                          replay_records(dropped, options=options).map_value().segments)
    stamps, matched, var, x, y = (np.array(c) for c in zip(*rows))
    assert np.array_equal(stamps, 1000.0 + drive.stamps)      # every scan posed, in order
    assert matched[1:100].all() and not matched[100:130].any() and matched[130:].mean() > 0.95
    assert var[100:130].min() >= var[99] and var[129] > 10 * var[99]     # its spread grows
    err = np.hypot(x - drive.poses[:, 0], y - drive.poses[:, 1])
    assert err[130:].max() <= 0.05, err[130:].max()


def test_scans_that_see_nothing_are_not_load_nor_missing_poses():
    # A review of e487f9b (session 67): once scans with no usable reading were queued to be
    # posed, load shedding counted them (max_queue 5, the odometry 0.65 s late around six of
    # them: 10 scans dropped against 2, four of them usable, and another map), and those whose
    # pose could not come were told as 'no pose' (before the odometry started: 'too_old').
    drive = make_drive('sim:office', 1)
    stamps = 1000.0 + drive.stamps
    blind = {60, 61, 63, 64, 66, 67}
    scans, other = [], []
    for r in records(drive, drift=1):
        if not isinstance(r, Scan):
            other.append(r)
        elif len(scans) < 200:
            scans.append(dataclasses.replace(r, ranges=np.full(len(r.ranges), np.inf, np.float32))
                         if len(scans) in blind else r)
    events, last = [], 0.0
    for i, r in enumerate(other):       # (arrival, order, record): late odometry at 5.8-6.8 s
        last = max(last, r.stamp + (0.65 if stamps[58] <= r.stamp <= stamps[68] else 0.02))
        events.append((last, 1, i, r))
    events += [(r.stamp, 0, i, r) for i, r in enumerate(scans)]
    events.sort(key=lambda e: e[:3])

    def live(skip=()):
        now = [0.0]
        session = MappingSession(None, SessionOptions(pose_source='odom', scan_matching=True,
                                                      max_queue=5, wait=3.0),
                                 clock=lambda: now[0])
        for t, _, i, r in events:
            if not (isinstance(r, Scan) and i in skip):
                now[0] = max(now[0], t)
                session.add(r)
                session.step()
        session.flush()
        return session
    seen, without = live(), live(skip=blind)
    assert seen.skipped == {'bad scan: no_valid_ranges': 6, 'dropped: queue_full': 2}
    assert without.skipped == {'dropped: queue_full': 2} and seen.used == without.used == 192
    assert np.array_equal(seen.map_value().segments, without.map_value().segments)
    # before the odometry starts: unusable first, as they were
    early = [r for r in records(drive, drift=1)[:400] if isinstance(r, Scan)
             or r.stamp >= stamps[5] - 1e-6 or getattr(r, 'static', False)]
    early = [dataclasses.replace(r, ranges=np.full(len(r.ranges), np.inf, np.float32))
             if isinstance(r, Scan) and r.stamp < stamps[5] - 1e-6 else r for r in early]
    session = replay_records(early, options=SessionOptions(pose_source='odom',
                                                           scan_matching=True))
    assert session.skipped == {'bad scan: no_valid_ranges': 5}


def test_a_featureless_corridor_does_not_slide():
    # One side of a 60 m corridor loop (2 m wide, the laser's range 12 m): in its middle the
    # scans see two parallel walls and nothing along the axis. The matcher keeps the odometry's
    # motion along the axis (no slide: a scan never moves along it by itself) and corrects
    # what the scans see: across the axis and the heading.
    world = corridor_loop(side=60.0)
    drive = simulate_drive(world, LaserSpec(noise=0.01), rng=5, waypoints=[(1, 1), (59, 1)])
    out = {}
    for matching in (True, False):
        session = replay_records(records(drive, drift=6),
                                 options=SessionOptions(scan_matching=matching,
                                                        keep_points=True))
        traj = session.map_value().trajectory
        assert len(traj) == len(drive.poses)
        out[matching] = traj[:, 1:]
    odom = OdometryDrift().apply(drive.poses, 6, stamps=drive.stamps)  # as drive_messages sent
    assert np.allclose(out[False], odom)
    # along the axis each matched step is the odometry's step (turned by the matched heading)
    est = out[True]
    step = se2_compose(se2_inverse(odom[:-1]), odom[1:])
    c, s = np.cos(est[:-1, 2]), np.sin(est[:-1, 2])
    expected = c * step[:, 0] - s * step[:, 1]
    middle = (drive.poses[1:, 0] > 14) & (drive.poses[1:, 0] < 46)
    slide = np.abs(np.diff(est[:, 0]) - expected)[middle]
    assert middle.sum() > 100 and slide.max() < 0.003, slide.max()
    across = np.abs(est[:, 1] - drive.poses[:, 1])
    yaw = np.abs(np.angle(np.exp(1j * (est[:, 2] - drive.poses[:, 2]))))
    # (the map starts 0.002 rad off, from the first scans: 10 cm across after 58 m)
    assert across.max() < 0.15 and yaw.max() < 0.01, (across.max(), yaw.max())
    assert np.abs(odom[:, 1] - drive.poses[:, 1]).max() > 1.0   # the odometry drifts across
    assert np.abs(np.angle(np.exp(1j * (odom[:, 2] - drive.poses[:, 2])))).max() > 0.05


@pytest.mark.parametrize('pose_source', ['odom', 'tf'])
def test_a_localizer_trajectory_has_the_base_poses(pose_source):
    # The node's setting: scan matching into the fixed frame 'map' (it broadcasts map -> odom),
    # the laser 0.2 m ahead of base_link. The trajectory rows (MAP.json, export) are the base's
    # poses; they were the laser's (0.2 m off) when the base was looked up in 'map', which only
    # the session itself provides, and the odometry's motion was then the laser's.
    drive = simulate_drive(office_floor(), LaserSpec(noise=0.01), step=0.4, rng=7)
    mount = np.asarray(SIM_MOUNT, dtype=float)
    truth = se2_compose(drive.poses, se2_inverse(mount))
    odom = OdometryDrift().apply(truth, 0)
    moved = dataclasses.replace(drive, poses=se2_compose(odom, mount))
    recs = flat_records(drive_messages(moved, map_to_odom=None))
    session = replay_records(recs, options=SessionOptions(
        pose_source=pose_source, scan_matching=True, fixed_frame='map', keep_points=True))
    traj = session.map_value().trajectory
    err = np.hypot(*(traj[:, 1:3] - truth[:, :2]).T)
    assert len(traj) == len(truth) and np.sqrt(np.mean(err ** 2)) < 0.03, err.max()
    assert np.abs(np.hypot(*(odom[:, :2] - truth[:, :2]).T)).max() > 1.0   # the odometry drifts
    # The yaw is wrapped into [-pi, pi), as the poses are given (it ran beyond pi before)
    assert traj[:, 3].min() >= -np.pi and traj[:, 3].max() < np.pi
    assert np.abs(np.angle(np.exp(1j * (traj[:, 3] - truth[:, 2])))).max() < 0.05


def test_drifting_odometry_and_a_moving_sensor_map_as_true_poses_do():
    # with true poses (and motion compensation) every wall is found: F1 1.0
    drive, s = replay('sim:office,moving_sensor=1,turn=0.2', 1, drift=1)
    assert s['rms'] <= 0.05 and s['walls']['f1'] == 1.0, (s['rms'], s['walls'])


@functools.lru_cache(maxsize=1)
def _office_turning():
    return make_drive('sim:office,moving_sensor=1,turn=0.2', 1)


@pytest.mark.parametrize('drift', (3, 8, 12))
def test_drifting_odometry_and_a_moving_sensor_keep_each_map_true_to_itself(drift):
    # Issue 19's office bar over drift seeds 3, 8 and 12, read as the absolute trajectory error
    # (the trajectory aligned rigidly to the truth, as the drifted Radish logs' 0.25 m is read)
    # with the walls of the map moved by the same alignment. As the poses stand 6 of the 12 seeds
    # of benchmarks/office_drift.py meet 5 cm (its table of 2026-11-30; on 2026-11-29 4 of 12,
    # 5 with numpy 1.26): the drift model's white
    # heading steps bend the first scans through the per-beam compensation and turn the whole map
    # frame by up to 0.016 rad (with the beams taken at once all 12 meet it as they stand). Each
    # map holds: ATE <= 0.040 m, aligned F1 1.00 on every seed (numpy 2.4 and 1.26). One test per
    # seed, so the two test workers share them. The three are the twelve's largest ATE in
    # benchmarks/office_drift.py's table (0.020, 0.027, 0.031 m; 2026-11-30, Intel Xeon VM), which
    # maps all twelve; seeds 1-12 each passed here on 2026-12-01. Each costs 8-10 s, and the suite
    # has to stay under 20 minutes.
    drive = _office_turning()
    session = replay_records(records(drive, drift),
                             options=SessionOptions(scan_matching=True, keep_points=True))
    value = session.map_value()
    traj = value.trajectory
    truth = drive.poses[np.searchsorted(1000.0 + drive.stamps, traj[:, 0] - 1e-6)]
    te = trajectory_error(traj[:, 1:], truth)
    moved = transform(value.segments.reshape(-1, 2), te['alignment']).reshape(-1, 2, 2)
    walls = B.wall_scores(moved, drive.world.walls, drive.world.distance,
                          points=drive.points())
    assert te['ate'] <= 0.05 and walls['f1'] == 1.0, (drift, te['ate'], walls)


XEON_SEED3 = pytest.mark.xfail(strict=False, reason=(
    "chaotic in the CPU's rounding: with the evidence per square alone, seed 3 maps walls F1 "
    '>= 0.95 on the AMD EPYC VMs of stops 30-34, 0.89 on an Intel Xeon VM (2026-11-28: '
    'precision 0.81, 7 of 36 segments off the walls; 0.061 m RMS, within the bar) and 0.945 '
    'on another AMD EPYC VM (2026-11-28, 0.060 m RMS). The same on e79bbef, before the '
    'session that marked it'))


PER_SQUARE = IncrementalConfig(free_space_window=10, free_space_ghosts=0,
                               free_space_hit_margin=0.0, free_space_memory=0.0)
"""The free-space evidence per square alone (no ghosts, hit margin or memory)."""


@pytest.mark.parametrize('seed', [pytest.param(3, marks=XEON_SEED3)])
def test_a_person_walking_ahead_leaves_the_walls_alone_with_the_evidence(seed):
    # The walls F1 of the second run below (the evidence per square alone), on its own: it
    # depends on the CPU for seed 3; the poses and holds below do not. (Seed 1's, the same
    # run as the one of WALKER_SEEDS there, is judged there.)
    drive = make_drive('sim:office_dynamic', seed)
    session = replay_records(records(drive), PER_SQUARE,
                             SessionOptions(scan_matching=True, keep_points=True))
    s = score(drive, session)
    assert s['walls']['f1'] >= 0.95, (s['rms'], s['walls'])


WALKER_SEEDS = (1, 4, 7, 8)
"""
Drive seeds of the dynamic office (the people's paths and the robot's vary with the seed).

Four of benchmarks/walker_ahead.py's eight (``--seeds 1 2 3 4 5 6 7 8`` maps them all): the
two largest errors of each setting. Drives 1-8 on 2026-12-01 (Intel Xeon VM, numpy 2.4, 424df6c),
RMS (m) / walls F1 without the evidence: 0.016/0.82, 0.070/0.81, 0.051/0.85, 0.039/0.83,
0.064/0.82, 0.033/0.78, 0.141/0.48, 0.110/0.52 (median 0.058); with it per square: 0.068/1.00,
0.036/0.97, 0.042/0.98, 0.064/0.96, 0.063/1.00, 0.015/0.98, 0.034/1.00, 0.035/0.98 (median
0.039). Over these four the medians are 0.075 and 0.050 m; eight drives cost 84 s of the
suite, which has to stay under 20 minutes.
"""


@pytest.mark.parametrize('evidence', [False, True], ids=['without evidence', 'per square'])
def test_a_person_walking_ahead_does_not_drag_the_matched_poses(evidence):
    # The dynamic office with true odometry: a person walks along the corridor ahead of the
    # robot, in its direction, twice. The corridor's walls say nothing along its axis; the
    # person, a tenth of the scan, pulled every match back by 8-12 cm and the robot followed
    # them (1.6 m RMS on seed 1, 1.9 m on seed 3, walls F1 0.04 / 0.16). A pull the odometry's
    # error cannot explain, along a direction established walls do not carry, is held, and so
    # is any pull along a weak direction the person-sized runs of the last scans carry; the
    # person's arcs that the scan sees through are not matched to (session.MATCH_SEEN_THROUGH).
    # The evidence per square alone (no ghosts, hit margin or memory) clears the person's
    # track from the map the scans are matched to.
    # Over several drives (WALKER_SEEDS): one drive's error is chaotic in the floating-point
    # rounding (seed 3 with the evidence: 0.060 m with numpy 2.4, 0.133 with numpy 1.26 before the
    # arcs seen through were left out; 0.085 / 0.047 since), so the bars hold for the median drive,
    # and no drive may be dragged (0.25 m) or lose the walls (F1 0.4 without the evidence). Medians
    # since: 0.060 / 0.069 m with numpy 2.4, 0.081 / 0.052 m with numpy 1.26. Since the person's
    # chords are transient (register.TRANSIENT_SHARE), over chord lengths 0.14-0.16 m
    # (benchmarks/walker_chords.py, 24 drives) 0.053 / 0.047 m where they were 0.130 / 0.073 m.
    # (Walls F1 >= 0.95 with the evidence: test_a_person_walking_ahead_leaves_the_walls_alone_
    # with_the_evidence, since it depends on the CPU.) One test per configuration, so the two
    # test workers share them.
    config, rms, f1 = ((PER_SQUARE, 0.08, None) if evidence else
                       (IncrementalConfig(free_space_window=0), 0.15, 0.4))
    errors = []
    for seed in WALKER_SEEDS:
        drive = make_drive('sim:office_dynamic', seed)
        session = replay_records(records(drive), config,
                                 SessionOptions(scan_matching=True, keep_points=True))
        s = score(drive, session)
        assert s['rms'] < 0.25 and (f1 is None or s['walls']['f1'] >= f1), \
            (config, seed, s['rms'], s['walls'])
        if evidence and seed == 1:      # the walls left alone (the test above, for seed 3)
            assert s['walls']['f1'] >= 0.95, (s['rms'], s['walls'])
        assert session.held >= 10 and session.matches['matched'] == len(drive.poses) - 1
        errors.append(s['rms'])
    assert np.median(errors) < rms, (config, np.round(errors, 3))


ALL_EVIDENCE = ('chaotic in the rounding: with all of the evidence (config/free_space.yaml), '
                'seed 1 gives 0.076 m RMS, walls F1 1.00 on an AMD EPYC VM with numpy 2.4 '
                '(2026-11-29), 0.039 m with numpy 1.26; before the arcs seen through were left '
                'out of the matches 0.090 and 0.117 m on two AMD EPYC VMs, 0.079 m on an Intel '
                'Xeon VM. Seed 3 passes since (0.037 / 0.038 m, F1 1.00; 0.179 m, F1 0.54 '
                'before)')


@pytest.mark.parametrize('seed', [
    pytest.param(1, marks=pytest.mark.xfail(strict=False, reason=ALL_EVIDENCE)), 3])
def test_a_person_walking_ahead_with_all_of_the_evidence(seed):
    drive = make_drive('sim:office_dynamic', seed)
    session = replay_records(records(drive), IncrementalConfig(free_space_window=10),
                             SessionOptions(scan_matching=True, keep_points=True))
    s = score(drive, session)
    assert s['rms'] < 0.08 and s['walls']['f1'] >= 0.95, (s['rms'], s['walls'])


def test_the_default_evidence_is_off_with_scan_matching_and_on_without():
    # free_space_window -1 (the default): the evidence assumes the poses are right; with the
    # scans matched to the map it would cut the walls a misplaced match sees through, which
    # later matches anchor on. A window given is used in both modes.
    for options, window in ((SessionOptions(), 10), (SessionOptions(scan_matching=True), 0),
                            (SessionOptions(pose_source='scan'), 0)):
        assert MappingSession(options=options).mapper.config.free_space_window == window
        given = MappingSession(IncrementalConfig(free_space_window=5), options)
        assert given.mapper.config.free_space_window == 5


@pytest.mark.xfail(strict=True, reason='issue 19: with the person walking ahead, pulls below 5 '
                   'sigma of the odometry are taken, and without the evidence (the default '
                   "with scan matching) the person's track (14 / 9 fragments of 0.04-0.27 m) "
                   "and the door leaf (the north wall's segment runs on across the doorway) "
                   'stay: 0.061 / 0.052 m RMS, walls F1 0.77 / 0.85 (2026-11-28); 0.047 / '
                   '0.034 m, F1 0.88 / 0.83 since the arcs seen through are left out of the '
                   'matches (numpy 2.4; numpy 1.26: 0.040 / 0.106 m, F1 0.84 / 0.52)')
@pytest.mark.parametrize('seed', [1, 3])
def test_a_person_walking_ahead_maps_as_true_poses_do(seed):
    drive, s = replay('sim:office_dynamic', seed)
    assert s['rms'] <= 0.05 and s['walls']['f1'] >= 0.9, (s['rms'], s['walls'])


@pytest.mark.xfail(strict=True, reason='issue 19: along 11-14 m of each 30 m side of the '
                   'corridor loop no cross wall is within the 12 m range: the odometry error '
                   'of 5 % a step adds up (about 9 cm a side): 14 cm RMS (11 along, 9 across), '
                   'walls F1 0.56 (2026-11-28). Localized on the map made with true poses '
                   '(mapping off), the same drive and drift seed still give 6.4 cm RMS '
                   '(2026-11-29)')
def test_drifting_odometry_and_a_moving_sensor_in_the_corridors_map_as_true_poses_do():
    drive, s = replay('sim:corridors,moving_sensor=1,turn=0.2', 1, drift=1)
    assert s['rms'] <= 0.05 and s['walls']['f1'] == 1.0, (s['rms'], s['walls'])


# -- scans only ----------------------------------------------------------------------------------
def test_scan_only_drive_maps_every_wall_within_10cm():
    # No odometry, no TF: constant velocity from the last two matched poses, refined against
    # the map (and, before the map starts, against the previous scans). 10 Hz, 1 m/s, turning
    # in place at 1 rad/s.
    drive, s = replay('sim:hall,step=0.1,turn=0.1', seed=3, pose_source='scan')
    assert s['used'] == len(drive.poses)
    assert s['walls']['recall'] == 1.0 and s['walls']['precision'] == 1.0, s['walls']
    assert s['rms'] < 0.05


def test_scan_only_office_drive_maps_every_wall_within_10cm():
    # The office corridor's only cue along its axis is a few door gaps: a weak constraint the
    # matcher must use in scan mode, or the robot that stops to turn and starts again is kept
    # standing still by the constant-velocity prediction and the map slides (2.7 m RMS).
    drive, s = replay('sim:office,step=0.1,turn=0.1', seed=1, pose_source='scan')
    assert s['used'] == len(drive.poses)
    assert s['walls']['recall'] == 1.0 and s['walls']['precision'] == 1.0, s['walls']
    assert s['rms'] < 0.05 and s['err'].max() < 0.1, (s['rms'], s['err'].max())


def test_scans_alone_from_a_spinning_lidar_are_deskewed_with_their_own_matched_motion():
    # A 5 Hz lidar sweeping over its whole period, no pose data: each scan's beams are placed
    # from the motion between matched poses. With the motion of the interval before, the error
    # fed back (too fast a turn deskewed, the match turns back by half the excess, the next
    # velocity errs the other way): heading errors alternating in sign scan after scan, p95
    # 5.7 deg while driving straight, 0.16 m RMS, walls precision 0.18. Now the scan is matched
    # again with the motion its match implies. (A scan at the start or end of a turn in place
    # is still deskewed with the motion before it: up to 4 deg, one scan each.)
    drive, s = replay('sim:hall,rate=5,step=0.04,turn=0.2,moving_sensor=1', seed=1,
                      pose_source='scan')
    assert s['used'] == len(drive.poses)
    turning = np.abs(np.angle(np.exp(1j * np.diff(drive.poses[:, 2])))) > 1e-6
    near = np.zeros(len(drive.poses), dtype=bool)       # scans around a turn's start or end
    for k in np.flatnonzero(np.diff(turning.astype(int))) + 1:
        near[max(0, k - 1):k + 2] = True
    yaw = np.degrees(s['yaw'][~near[s['index']]])
    assert np.percentile(yaw, 95) < 0.3 and yaw.max() < 1.0, (np.percentile(yaw, 95), yaw.max())
    assert s['rms'] < 0.05 and s['walls']['recall'] == 1.0, (s['rms'], s['walls'])
    assert s['mean_distance'] < 0.025


@pytest.mark.parametrize('start, found', [(0, True), (150, False)])
def test_scans_alone_played_again_are_searched_for_where_the_first_scan_was(start, found):
    # A scan-only recording played again (its clock jumps back): the first pass's motion
    # placed the second pass's scans, and the map took 21 segments off the walls (precision
    # 0.49). Now the scans are searched for where the first scan was: a pass from the start
    # is found and mapped, one from 5 m away is not mapped, and the map stays right.
    drive = make_drive('sim:office,step=0.1,turn=0.1', 1)
    scans = records(drive, scans_only=True)
    again = [dataclasses.replace(r, stamp=scans[k].stamp)
             for k, r in enumerate(scans[start:start + 100])]
    warned = []
    session = MappingSession(options=SessionOptions(pose_source='scan', keep_points=True),
                             warn=lambda cause, text: warned.append(cause))
    for record in scans[:300] + again:
        session.add(record)
        session.step()
    session.flush()
    s = score(drive, session, drive.poses[0])
    assert warned.count('time_jump') == 1 and s['walls']['precision'] == 1.0, (warned, s['walls'])
    assert session.used == (400 if found else 300)
    assert session.matches['found near the estimate' if found else
                           'not found near the estimate'] >= 1


def test_scan_only_needs_no_pose_data_and_starts_at_the_origin():
    drive = make_drive('sim:hall,step=0.1,turn=0.1', 3)
    session = MappingSession(options=SessionOptions(pose_source='scan', keep_points=True))
    assert session.options.scan_matching
    scans = records(drive, scans_only=True)
    for scan in scans[:20]:
        session.add(scan)
        session.step()                  # never waits: each scan is posed as it comes
        assert session.used == scans.index(scan) + 1
    traj = session.map_value().trajectory
    assert np.array_equal(traj[0, 1:], [0.0, 0.0, 0.0]) and session.fixed_frame == 'map'
    # relative to the first scan, the poses follow the drive
    truth = se2_compose(se2_inverse(drive.poses[0]), drive.poses[:20])
    assert np.hypot(*(traj[:, 1:3] - truth[:, :2]).T).max() < 0.05
    with pytest.raises(ValueError, match='pose_source must be tf, odom or scan'):
        SessionOptions(pose_source='lidar')


def test_scans_alone_put_the_root_of_the_laser_tree_under_the_map():
    # Scan mode broadcast nothing, so RViz had no transform from the map to the laser and
    # showed neither the scans nor the robot. The session now names what the node broadcasts
    # under the map frame: the frame the laser's static mounts hang from, at its matched pose,
    # unless a transform on /tf already gives that frame a parent (odometry: tf2 would see two).
    from test_session import tf
    drive = make_drive('sim:hall,step=0.1,turn=0.1', 3)
    mount = np.array([0.2, -0.05, 0.3])
    scans = records(drive, scans_only=True)[:30]
    for odometry in (False, True):
        session = MappingSession(options=SessionOptions(pose_source='scan'))
        session.add(tf(0.0, 'base_link', 'laser', mount, static=True))
        session.add(tf(0.0, 'map', 'base_link', (5.0, 5.0, 1.0)))   # our own, read back
        for k, scan in enumerate(scans):
            if odometry:
                session.add(tf(scan.stamp, 'odom', 'base_link', (0.1 * k, 0.0, 0.0)))
            session.add(scan)
            session.step()
        loc = session.localization
        assert loc.scan_frame == 'laser' and loc.matched
        frame, pose, why = session.scan_root(loc)
        if odometry:
            assert frame is None and why.startswith('base_link already has a parent on /tf '
                                                    '(odom -> base_link)'), why
        else:
            assert frame == 'base_link' and why == ''
            assert np.allclose(se2_compose(pose, mount), loc.pose, atol=1e-12)
            truth = se2_compose(se2_inverse(drive.poses[0]), drive.poses[len(scans) - 1])
            assert np.hypot(*(se2_compose(pose, mount)[:2] - truth[:2])) < 0.05
    # a scan frame without a mount is its own root
    session = MappingSession(options=SessionOptions(pose_source='scan'))
    for scan in scans[:3]:
        session.add(scan)
        session.step()
    frame, pose, _ = session.scan_root(session.localization)
    assert frame == 'laser' and np.array_equal(pose, session.localization.pose)


def test_scans_alone_of_an_upside_down_laser_are_not_mirrored():
    # Scan mode placed every scan upright, whatever the laser's mount on /tf_static said: an
    # upside-down laser (roll pi; its beams listed the other way round) gave the mirror image
    # of the room, 4 mm from the mirrored walls, 0 % contradicted, unwarned (an audit). Its
    # mount now turns its beams over as in tf mode: the map and the poses are the upright
    # laser's, and the robot's pose it broadcasts puts the laser where the scans were placed.
    from polyline_mapper.poses import mount_quaternion
    from test_session import tf
    drive = make_drive('sim:hall,step=0.1,turn=0.1', 3)
    mount = np.array([0.2, -0.05, 0.3])
    scans = records(drive, scans_only=True)[:120]
    sessions = []
    # upright; flipped with its mount on /tf_static; flipped with its mount sent on /tf with
    # every scan (a ROS 1 static_transform_publisher, a converted bag: still mirrored after
    # the first fix, an audit of it)
    for flip, static in ((False, True), (True, True), (True, False)):
        session = MappingSession(options=SessionOptions(pose_source='scan', keep_points=True))
        mounted = tf(0.0, 'base_link', 'laser', mount, static=static,
                     quat=mount_quaternion(mount[2], flip))
        session.add(mounted)
        session.add(tf(0.0, 'odom', 'base_link', (0.0, 0.0, 0.0)))     # odometry: no flip
        for scan in scans:
            if flip:
                scan = dataclasses.replace(scan, ranges=scan.ranges[::-1].copy())
            if not static:
                session.add(dataclasses.replace(mounted, stamp=scan.stamp))
            session.add(scan)
            session.step()
        sessions.append(session)
    values = [s.map_value() for s in sessions]
    assert [len(v.trajectory) for v in values] == [len(scans)] * 3
    # (the beams' other order changes which points the matcher samples: within 1.1 cm)
    truth = se2_compose(se2_inverse(drive.poses[0]), drive.poses[:len(scans)])
    for value in values:
        assert np.hypot(*(value.trajectory[:, 1:3] - truth[:, :2]).T).max() < 0.05
    walls = [B.wall_scores(transform(v.segments.reshape(-1, 2), drive.poses[0]).reshape(-1, 2, 2),
                           drive.world.walls, drive.world.distance) for v in values]
    assert all(w['precision'] == 1.0 and w['found'] == walls[0]['found'] for w in walls), walls
    # The broadcast: no odometry above the mount here; the laser is where its scans are.
    session = MappingSession(options=SessionOptions(pose_source='scan'))
    session.add(tf(0.0, 'base_link', 'laser', mount, static=True,
                   quat=mount_quaternion(mount[2], True)))
    for scan in scans[:30]:
        session.add(dataclasses.replace(scan, ranges=scan.ranges[::-1].copy()))
        session.step()
    loc = session.localization
    frame, pose, why = session.scan_root(loc)
    assert (frame, why) == ('base_link', '')
    assert np.allclose(se2_compose(pose, mount), loc.pose, atol=1e-12)
    # A mount that comes after the first scans: they stay placed as they were (upright),
    # said once; after ~/reset (a new map) the mount decides.
    warned = []
    session = MappingSession(options=SessionOptions(pose_source='scan'),
                             warn=lambda cause, text: warned.append((cause, text)))
    for k, scan in enumerate(scans[:20]):
        if k == 10:
            session.add(tf(0.0, 'base_link', 'laser', mount, static=True,
                           quat=mount_quaternion(mount[2], True)))
        session.add(dataclasses.replace(scan, ranges=scan.ranges[::-1].copy()))
        session.step()
    assert [c for c, _ in warned if c == 'laser_flip'] == ['laser_flip'], warned
    assert 'now say it is upside down' in dict(warned)['laser_flip']
    assert not session.poses.upside_down('nothing') and session.poses._flips == {'laser': False}
    session.reset()
    session.add(scans[20])
    session.step()
    assert session.poses._flips == {'laser': True}


def test_scans_alone_follow_one_laser_and_refuse_another_in_one_line():
    # Two lasers on one topic (front, and rear turned half a turn): scan mode predicted each
    # scan from the last ones, whichever laser took them, and drew 56 segments with 72 % of
    # the map's length contradicted (an audit). The second laser's scans are now skipped with
    # one line, as with pose_source odom.
    drive = make_drive('sim:hall,step=0.1,turn=0.1', 3)
    warned = []
    session = MappingSession(options=SessionOptions(pose_source='scan'),
                             warn=lambda cause, text: warned.append((cause, text)))
    for k, scan in enumerate(records(drive, scans_only=True)[:40]):
        session.add(scan if k % 2 == 0 else dataclasses.replace(scan, frame_id='laser_rear'))
        session.step()
    assert session.used == 20 and session.skipped['no pose: laser_frame'] == 20
    text = dict(warned)['laser_frame']
    assert "scan in frame 'laser_rear', but scan mode follows one laser, 'laser'" in text
    assert '~/reset follows' in text and '\n' not in text
    # A laser whose frame changed name (a driver restarted with another configuration): after
    # ~/reset, a new map, the session follows it (it skipped it for good: an audit).
    session.reset()
    for scan in records(drive, scans_only=True)[40:60]:
        session.add(dataclasses.replace(scan, frame_id='laser_rear'))
        session.step()
    assert session.used == 40 and session.skipped['no pose: laser_frame'] == 20
    # ... on a saved map too (it kept the first laser there: an audit)
    saved = MappingSession(options=SessionOptions(pose_source='scan'))
    saved.load_map(session.map_value(), None)
    for k, scan in enumerate(records(drive, scans_only=True)[:40]):
        if k == 20:
            saved.reset()
        saved.add(dataclasses.replace(scan, frame_id='laser_rear') if k >= 10 else scan)
        saved.step()
    # (the reset puts the robot back at the start, searched for there: 2 scans lost)
    assert saved.skipped['no pose: laser_frame'] == 10 and saved.used >= 25, saved.skipped


def test_replay_pose_source_scan_from_the_command_line(tmp_path):
    from polyline_mapper.cli import main
    from polyline_mapper.formats.mapjson import read_map
    out = tmp_path / 'map.json'
    assert main(['replay', 'sim:hall,step=0.1,turn=0.1', '--pose-source', 'scan', '-o',
                 str(out), '-q']) == 0
    data = read_map(out)
    drive = make_drive('sim:hall,step=0.1,turn=0.1', 1)
    traj = data.value.trajectory
    assert data.value.frame_id == 'map' and len(traj) == len(drive.poses)
    assert np.array_equal(traj[0, 1:], [0.0, 0.0, 0.0])
    truth = se2_compose(se2_inverse(drive.poses[0]), drive.poses)
    assert np.sqrt(np.mean(np.sum((traj[:, 1:3] - truth[:, :2]) ** 2, axis=1))) < 0.05


def _scan_mode_node(tmp_path, name: str) -> tuple:
    """
    Start the node with pose_source scan and a peer that keeps every map -> X it broadcasts.

    Returns (the hall drive to play, node, peer, broadcast) once the node's inputs and map are
    matched; the caller closes the peer and stops the node.
    """
    pytest.importorskip('tf2_msgs.msg', reason='tf2_msgs is not built (run tools/dev.sh setup)')
    from polyline_mapper.ros.qos import TF_QOS
    from rosnode import NodeProcess, Peer
    node = NodeProcess(tmp_path, {'pose_source': 'scan', 'map_publish_period': 0.0,
                                  'stats_period': 0.0})
    peer = Peer(name)
    broadcast = []
    peer.node.create_subscription(
        peer.TFMessage, '/tf', lambda m: broadcast.extend(
            t for t in m.transforms if t.header.frame_id == 'map'), TF_QOS)
    try:
        assert peer.spin_until(lambda: peer.scan_pub.get_subscription_count() > 0
                               and peer.static_pub.get_subscription_count() > 0
                               and peer.node.count_publishers('/polyline_map') > 0, 60.0)
        peer.spin_for(0.5)
    except BaseException:
        peer.close()
        node.stop()
        raise
    return make_drive('sim:hall,step=0.1,turn=0.1', 3), node, peer, broadcast


@pytest.mark.slow
@pytest.mark.dds
def test_the_node_maps_scans_alone(tmp_path):
    # Over DDS: pose_source scan places the scans by themselves (no odometry; /tf and
    # /tf_static only to learn where the laser hangs) and publishes a map whose walls, seen from
    # the first scan's laser pose, are the world's; it broadcasts map -> base_link (the frame
    # the laser's mount hangs from) at each matched pose, so RViz shows the scans and the robot.
    from polyline_mapper.ros.messages import transform_msg
    from rosnode import map_segments, stamp_of
    drive, node, peer, broadcast = _scan_mode_node(tmp_path, 'test_peer_scan_only')
    try:
        assert peer.odom_pub.get_subscription_count() == 0
        messages = list(drive_messages(drive))
        static = [r for _, topic, r in messages if topic == '/tf_static']
        mount = np.array(SIM_MOUNT)
        assert static[0][0].child == 'laser' and static[0][0].parent == 'base_link'
        peer.static_pub.publish(peer.TFMessage(transforms=[transform_msg(t) for t in static[0]]))
        peer.spin_for(0.5)
        last = peer.play(messages, 25.0, mode='scan')
        assert peer.spin_until(lambda: peer.maps and stamp_of(peer.maps[-1]) == pytest.approx(
            last, abs=1e-6), 60.0), node.stderr()[-3000:]
        peer.spin_until(lambda: broadcast and stamp_of(broadcast[-1]) == pytest.approx(
            last, abs=1e-6), 10.0)
        msg = peer.maps[-1]
        assert msg.header.frame_id == 'map'
        segs = map_segments(msg)
        world = transform(segs.reshape(-1, 2), drive.poses[0]).reshape(-1, 2, 2)
        scores = B.wall_scores(world, drive.world.walls, drive.world.distance,
                               points=drive.points())
        assert scores['recall'] == 1.0 and scores['precision'] == 1.0, scores
    finally:
        peer.close()
        assert node.stop() == 0
    assert {t.child_frame_id for t in broadcast} == {'base_link'}
    assert len(broadcast) >= 0.9 * len(drive.poses), (len(broadcast), len(drive.poses))
    # each is the robot base where its scan's matched laser pose puts it, in the first scan's
    # laser frame (the map's origin)
    # (the peer stamps scan k at last - (n - 1 - k) / rate)
    k = (np.array([stamp_of(t) for t in broadcast]) - last) * 25.0 + len(drive.poses) - 1
    assert np.allclose(k, np.rint(k), atol=1e-3) and len(set(np.rint(k))) == len(k)
    k = np.rint(k).astype(int)
    got = np.array([[t.transform.translation.x, t.transform.translation.y,
                     2 * np.arctan2(t.transform.rotation.z, t.transform.rotation.w)]
                    for t in broadcast])
    truth = se2_compose(se2_inverse(drive.poses[0]),
                        se2_compose(drive.poses[k], se2_inverse(mount)))
    err = np.hypot(*(got[:, :2] - truth[:, :2]).T)
    assert np.sqrt(np.mean(err ** 2)) < 0.05, err


@pytest.mark.slow
@pytest.mark.dds
def test_the_node_waits_for_the_lasers_mount_before_broadcasting_scans_alone(tmp_path):
    # A node audit: scans that came before the laser's /tf_static (discovery races them) were
    # broadcast as map -> laser, the laser's root then, and once the mount came the laser had
    # two parents (base_link, map; REP 105: one). A scan waits for its transforms up to
    # transform_timeout; the broadcast of a laser without a parent does too.
    from polyline_mapper.ros.messages import transform_msg
    drive, node, peer, broadcast = _scan_mode_node(tmp_path, 'test_peer_scan_race')
    try:
        messages = [m for m in drive_messages(drive) if m[1] in ('/scan', '/tf_static')]
        scans = [m for m in messages if m[1] == '/scan']
        static = [r for _, topic, r in messages if topic == '/tf_static']
        t0 = time.time()
        peer.play(scans[:4], 25.0, mode='scan', t0=t0)         # 0.16 s of scans, no mount yet
        peer.spin_for(0.1)
        peer.static_pub.publish(peer.TFMessage(transforms=[transform_msg(t) for t in static[0]]))
        last = peer.play(scans[4:60], 25.0, mode='scan', t0=t0 + 4 / 25.0)
        assert peer.spin_until(lambda: broadcast and abs(
            broadcast[-1].header.stamp.sec + 1e-9 * broadcast[-1].header.stamp.nanosec - last)
            < 1e-6, 20.0), node.stderr()[-3000:]
    finally:
        peer.close()
        assert node.stop() == 0
    assert {t.child_frame_id for t in broadcast} == {'base_link'}
    assert len(broadcast) >= 50


def test_scan_consistency_tells_the_true_steps_from_noisy_ones():
    # A reference-free check of a trajectory (core.metrics.scan_consistency): the office drive
    # with its true laser poses, and with 2 cm / 0.3 deg of noise on every step.
    drive = make_drive('office', seed=2, noise=0.01, beams=360)
    angles = drive.spec.angles()
    scans = [scan_to_points(r, angles, np.zeros(3), drive.spec.range_min, drive.spec.range_max)
             for r in drive.ranges]
    rng = np.random.default_rng(5)
    steps = se2_compose(se2_inverse(drive.poses[:-1]), drive.poses[1:])
    steps += rng.normal(size=steps.shape) * [0.02, 0.02, np.radians(0.3)]
    noisy = [drive.poses[0]]
    for step in steps:
        noisy.append(se2_compose(noisy[-1], step))
    true, off = scan_consistency(scans, drive.poses), scan_consistency(scans, np.array(noisy))
    assert true['pairs'] == off['pairs'] == len(scans) - 1
    # 1 cm range noise; the rest: surfaces the scan before did not see
    assert true['mean'] < 0.012 and true['share'] > 0.9
    assert off['mean'] > 1.5 * true['mean']
    with pytest.raises(ValueError):
        scan_consistency(scans, drive.poses[:-1])


def lds_drive(seed: int = 1, corridors: bool = False):
    """
    Return the office's first 12 waypoints driven with a TurtleBot3-class lidar.

    ``corridors``: the 10 m corridor loop (2 m wide) instead. As benchmarks/cheap_lidar.py:
    360 beams over the full circle at 5 Hz, taken over the scan time, 0.12-3.5 m, 1 % dropouts,
    range noise 1.5 cm plus 1 % of the range; 0.2 m/s, 1 rad/s.
    """
    spec = LaserSpec(beams=360, fov=2 * np.pi, range_min=0.12, range_max=3.5, noise=0.015,
                     dropout=0.01)
    if corridors:
        world = corridor_loop(width=2.0, side=10.0)
    else:
        world = office_floor()
        world.path = world.path[:12]
    drive = simulate_drive(world, spec, step=0.04, rate=5.0, rng=seed, turn=0.2, scan_time=0.2)
    rng = np.random.default_rng(1000 + seed)
    ranges = drive.ranges.copy()
    ok = np.isfinite(ranges)
    ranges[ok] += rng.normal(size=int(ok.sum())) * 0.01 * ranges[ok]
    drive.ranges = ranges
    return drive


def test_median_chord_knots_keep_a_turtlebot_class_lidar_on_course():
    # With noise that grows with the range, 'arc' knots (the default before 2026-11-30) turn
    # every match the same way:
    # perfect odometry, matched, ended 3.32 deg off, 0.225 m RMS, walls F1 0.24 (cheap_lidar.py;
    # 3.85 deg, 0.251 m before small slides along weak directions were held, 2026-11-29).
    # The knots of chord_knots 'median' do not depend on a reading's own noise: 0.01 deg,
    # 0.032 m, F1 0.97 (0.10 deg, 0.069 m before; numpy 2.4, AMD EPYC VM).
    drive = lds_drive()
    s = {knots: score(drive, replay_records(records(drive), options=SessionOptions(
        scan_matching=True, keep_points=True, chord_knots=knots))) for knots in ('arc', 'median')}
    assert np.degrees(s['arc']['yaw'][-1]) > 1.5          # arc's known limit (README)
    m = s['median']
    assert m['rms'] < 0.1 and np.degrees(m['yaw'][-1]) < 1.0 and m['walls']['f1'] >= 0.9, \
        (m['rms'], np.degrees(m['yaw'][-1]), m['walls'])


def test_true_odometry_matched_holds_a_turtlebot_class_lidar_along_its_corridors():
    # 10 m corridor loop, 2 m wide, a 3.5 m lidar: along each side the scans barely constrain the
    # axis. Corrections along it under the kernel scale (about 3 cm) were taken although 5 sigma of
    # a 4 cm step's odometry error is 1 cm: the matched pose lagged the true one (16 cm along an 8
    # m side with range-noise seed 2). One drive is chaotic across CPUs: seed 1 gave 0.047 m RMS,
    # walls F1 0.96 on an AMD EPYC VM and 0.039 m, F1 0.83 on an Intel Xeon one (its walls cut by
    # stubs), so the claim is judged over several drives. Drives 1-10 on the Xeon: RMS 0.032-0.103
    # m (median 0.052), F1 0.72-1.00 (median 0.92); with every correction taken
    # (register.WEAK_SIGMAS infinite, as before the hold) 0.119-0.260 m (median 0.183), F1
    # 0.21-0.76 (median 0.44). Drives 1-5 here (10 s each; the suite has to stay under 20 minutes):
    # on 2026-12-01 (Intel Xeon VM, 36daaa7) drives 1-5 gave RMS median 0.040 m, max 0.082, F1
    # median 0.947; drives 1-10 0.041 m, 0.082, 0.948 (drive 9: F1 0.78).
    rms, f1 = [], []
    for seed in range(1, 6):
        drive = lds_drive(seed, corridors=True)
        s = score(drive, replay_records(records(drive), options=SessionOptions(
            scan_matching=True, keep_points=True, chord_knots='median')))
        rms.append(s['rms'])
        f1.append(s['walls']['f1'])
    assert np.median(rms) < 0.065 and max(rms) < 0.15 and np.median(f1) >= 0.9, (rms, f1)


def test_the_lds01_preset_maps_a_turtlebot_class_lidar_without_stubs_across_its_walls():
    # Range noise 1.5 cm + 1 % of the range, the robot's true poses, no scan matching. The noise
    # scale estimated from the scans follows the near points (1.6 cm) and far returns off the
    # corridor loop's walls line up into short stubs across them (12 of 20 segments under
    # 0.5 m, F1 0.97); config/lds01.yaml fixes it at 2.5 cm: the 8 walls alone
    # (benchmarks/cheap_lidar.py --sigma 0.025: no stub on 5 drives, F1 1.00 on 10).
    from polyline_mapper.config import load_mapper_config
    preset = load_mapper_config(str(REPO / 'config' / 'lds01.yaml'))
    assert preset == IncrementalConfig(smemsf=dataclasses.replace(IncrementalConfig().smemsf,
                                                                  sigma=0.025))
    drive = lds_drive(corridors=True)
    out = {}
    for name, config in (('estimated', None), ('lds01', preset)):
        session = replay_records(records(drive), config, SessionOptions(keep_points=True))
        segs = np.asarray(session.map_value().segments)
        short = int(np.count_nonzero(np.hypot(*(segs[:, 1] - segs[:, 0]).T) < 0.5))
        out[name] = (len(segs), short, score(drive, session)['walls']['f1'], session.mapper.sigma)
    assert out['estimated'][1] >= 5 and out['estimated'][3] < 0.02, out     # the stubs
    assert out['lds01'][:3] == (8, 0, 1.0), out


def test_chord_knots_reach_the_session_from_the_node_and_the_command_line(capsys, tmp_path,
                                                                          monkeypatch):
    from polyline_mapper.cli import _replay_options, build_parser, main
    monkeypatch.chdir(tmp_path)
    from polyline_mapper.params import defaults, settings_from
    assert defaults()['chord_knots'] == 'median' == SessionOptions().chord_knots
    for knots in ('arc', 'median'):
        settings = settings_from(defaults() | {'chord_knots': knots})[0]
        assert settings.chord_knots == knots
        args = build_parser().parse_args(['replay', 'sim:office', '-o', 'm.json',
                                          '--chord-knots', knots])
        assert _replay_options(args, matching=True).chord_knots == knots
    plain = build_parser().parse_args(['replay', 'sim:office', '-o', 'm.json'])
    assert _replay_options(plain, matching=True).chord_knots == 'median'
    with pytest.raises(ValueError, match='chord_knots'):
        settings_from(defaults() | {'chord_knots': 'mean'})
    with pytest.raises(ValueError, match='chord_knots'):
        SessionOptions(chord_knots='mean')
    for knots in ('arc', 'median'):              # given, even as the default, without matching
        assert main(['replay', 'sim:office', '-o', 'm.json', '--chord-knots', knots]) == 2
        assert '--chord-knots applies to scan matching only' in capsys.readouterr().err


def _odometry_run(drive, odometry, pose_source='odom', again=None) -> dict:
    """Map ``drive`` with ``odometry`` (mount 0), played ``again`` after ``again`` s; score."""
    recs = flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0), odometry=odometry))
    if again is not None:
        recs += [dataclasses.replace(r, stamp=r.stamp + again) for r in recs]
    warned = []
    session = replay_records(recs, options=SessionOptions(
        pose_source=pose_source, scan_matching=True, keep_points=True),
        warn=lambda cause, text: warned.append((cause, text)))
    got = score(drive, session) if again is None else {}
    got['session'] = session
    got['odom_jump'] = [text for cause, text in warned if cause == 'odom_jump']
    got['jumps'] = session.stats().get('match_jumps', {})
    return got


def _booted_behind(n: int, j: int) -> tuple:
    """
    Return the first ``n`` scans of the 0.5 m/s simulated office and drifting odometry (seed 1).

    The odometry starts 0.3 m behind the robot's pose at scan ``j`` (the robot booted there),
    so that pose lies near the odometry's origin: (drive, odometry).
    """
    full = make_drive('sim:office,step=0.05', 1)
    drive = dataclasses.replace(full, poses=full.poses[:n], stamps=full.stamps[:n],
                                ranges=full.ranges[:n])
    base = np.asarray(drive.poses, dtype=np.float64)
    origin = se2_compose(base[j], np.array([-0.3, 0.0, 0.0]))
    return drive, se2_compose(se2_inverse(origin),
                              OdometryDrift().apply(base, 1, stamps=drive.stamps))


def _odom_run(recs) -> tuple:
    """Map ``recs`` (pose_source odom, scan matching); (trajectory rows, warning causes)."""
    warned = []
    session = replay_records(recs, options=SessionOptions(
        pose_source='odom', scan_matching=True, keep_points=True),
        warn=lambda cause, text: warned.append(cause))
    return np.asarray(session.map_value().trajectory), warned


@pytest.mark.parametrize('spec,pose_source', [
    ('sim:office', 'odom'), ('sim:office,moving_sensor=1,turn=0.2', 'tf'),
    ('sim:corridors,moving_sensor=1,turn=0.2', 'odom')])
def test_an_odometry_reset_mid_drive_is_warned_and_maps_no_shifted_copy(spec, pose_source):
    # A live-node audit: odometry whose driver restarted (its pose back to the origin while the
    # robot drove on) was taken for motion: the next scans were matched onto a copy of the map
    # shifted by the jump, every one 'matched', no warning (sim:office reset at scan 150: poses
    # 16.6 m off, walls F1 0.65). The jump is now seen (``ODOM_JUMP``), the robot predicted at
    # its last pace and map -> odom re-anchored; with a moving sensor the scan during which
    # the odometry jumped was spread along the jump (walls F1 0.79 office, 0.24 corridors) and
    # is now placed with the matched motion. The same drive without the reset is the control.
    drive = make_drive(spec, 1)
    base = np.asarray(drive.poses, dtype=np.float64)      # the laser on base_link (mount 0)
    odometry = OdometryDrift().apply(base, 1, stamps=drive.stamps)
    k = 150
    reset = odometry.copy()
    reset[k:] = se2_compose(se2_inverse(odometry[k]), odometry[k:])
    assert np.hypot(*odometry[k, :2]) > 5.0
    got = {'reset': _odometry_run(drive, reset, pose_source),
           'control': _odometry_run(drive, odometry, pose_source)}
    jumps = got['reset']['odom_jump']
    assert len(jumps) == 1 and 'its driver restarted' in jumps[0], jumps
    assert got['reset']['jumps'].get('odometry') == 1 and 'odometry' not in got['control']['jumps']
    for name in got:
        assert got[name]['used'] == len(drive.stamps), name
    # (the corridor loop drifts without loop closure, reset or not: its control's F1 is 0.37)
    assert got['reset']['walls']['f1'] >= got['control']['walls']['f1'], got
    assert got['control']['walls']['f1'] == 1.0 or 'corridors' in spec, got['control']['walls']
    assert got['reset']['rms'] < 1.2 * got['control']['rms'] + 0.005, (
        got['reset']['rms'], got['control']['rms'])


def test_a_second_reset_near_the_odometry_origin_is_judged_by_its_heading():
    # A helper audit: the odometry reset at scan 150 and again at 200, where it had driven only
    # back near its new origin: the second jump moves the robot 0.84 m off its pace (under
    # ODOM_JUMP's 1 m, left to the relocalization) but turns it by 83 deg, beyond the
    # matcher's heading search: mapped 19 m off after it (walls F1 0.63). Into a pose near the
    # odometry's origin its heading is judged too now (ODOM_JUMP_TURN, ODOM_RESET_REACH); the
    # simulated drives' 90 deg turns within a scan, which the scans confirm, change nothing
    # (the control: no jump).
    drive = make_drive('sim:office', 1)
    base = np.asarray(drive.poses, dtype=np.float64)
    odometry = OdometryDrift().apply(base, 1, stamps=drive.stamps)
    reset = odometry.copy()
    for k in (150, 200):
        reset[k:] = se2_compose(se2_inverse(reset[k]), reset[k:])
    pace = se2_compose(se2_inverse(reset[198]), reset[199])
    off = se2_compose(se2_inverse(pace), se2_compose(se2_inverse(reset[199]), reset[200]))
    assert np.hypot(off[0], off[1]) < ODOM_JUMP[0] and abs(off[2]) > 1.4, off
    assert np.allclose(reset[200], 0.0)           # (the reset: back at the origin)
    got = {'reset': _odometry_run(drive, reset), 'control': _odometry_run(drive, odometry)}
    jumps = got['reset']['odom_jump']
    assert len(jumps) == 2 and all('its driver restarted' in j for j in jumps), jumps
    assert '0.84 m and 83 deg off its pace' in jumps[1], jumps
    assert got['control']['odom_jump'] == [] and 'odometry' not in got['control']['jumps']
    assert got['reset']['used'] == len(drive.stamps)
    assert got['reset']['walls']['f1'] == got['control']['walls']['f1'] == 1.0, got
    assert got['reset']['rms'] < 1.2 * got['control']['rms'] + 0.005, (
        got['reset']['rms'], got['control']['rms'])


def test_odometry_at_half_the_scan_rate_is_no_heading_jump_away_from_its_origin(monkeypatch):
    # Odometry at 5 Hz under 10 Hz scans (every other message of a 5 m/s drive), interpolated
    # across the simulated office's 90 deg turns within a scan, steps its heading 0.5 rad and
    # more off its pace with no reset. Judged everywhere, the pace's match won there and
    # map -> odom was re-anchored on it: the drive ended 35 m off (walls F1 0.04; not judged:
    # at most 0.82 m off). Away from the odometry's origin a heading jump alone is not judged.
    import polyline_mapper.session as session_module
    drive = make_drive('sim:office,step=0.5', 1)
    odometry = OdometryDrift().apply(np.asarray(drive.poses, dtype=np.float64), 1,
                                     stamps=drive.stamps)
    index = {round(1000.0 + t, 6): i for i, t in enumerate(drive.stamps)}
    recs = flat_records(m for m in drive_messages(drive, mount=(0.0, 0.0, 0.0), odometry=odometry)
                        if m[1] != '/odom' or index[round(m[2].stamp, 6)] % 2 == 0)
    assert 0 < sum(isinstance(r, Odometry) for r in recs) < len(drive.stamps) / 2 + 1
    rows, warned = _odom_run(recs)
    assert 'odom_jump' not in warned, warned
    monkeypatch.setattr(session_module, 'ODOM_JUMP_TURN', (math.inf, math.inf))
    before, _ = _odom_run(recs)
    assert len(rows) > 150 and np.array_equal(rows, before)
    truth = np.asarray(drive.poses)[np.searchsorted(1000.0 + drive.stamps, rows[:, 0] - 1e-6)]
    assert np.max(np.hypot(*(rows[:, 1:3] - truth[:, :2]).T)) < 1.0


@pytest.mark.parametrize('spec, found', [('sim:office,step=0.05', True), ('sim:office', False)])
def test_an_odometry_driver_restart_after_a_silence_is_searched_for_on_the_map(spec, found):
    # A driver that restarts is silent for a while (1.2 s here: its scans are refused for the
    # gap in the odometry) and back at its origin. No pace carries over the gap, so it was
    # not judged: the scans after it were matched onto a copy of the map (the simulated office
    # at 0.5 m/s, reset at scan 615: 10.4 m RMS, walls F1 0.53). The scan is now searched for
    # around where the last pace leads, as after a gap in scan mode; at 2.5 m/s the robot may
    # be anywhere within 3 m and more: no scan is mapped after it (the map stays right), said.
    full = make_drive(spec, 1)
    n, k, silent = (700, 615, 12) if found else (200, 150, 12)
    drive = dataclasses.replace(full, poses=full.poses[:n], stamps=full.stamps[:n],
                                ranges=full.ranges[:n])
    base = np.asarray(drive.poses, dtype=np.float64)
    odometry = OdometryDrift().apply(base, 1, stamps=drive.stamps)
    reset = odometry.copy()
    reset[k:] = se2_compose(se2_inverse(odometry[k]), odometry[k:])

    def run(odometry):
        quiet = (1000.0 + drive.stamps[k - silent] - 1e-6, 1000.0 + drive.stamps[k] - 1e-6)
        recs = flat_records(m for m in drive_messages(drive, mount=(0.0, 0.0, 0.0),
                                                      odometry=odometry)
                            if m[1] != '/odom' or not quiet[0] <= m[2].stamp < quiet[1])
        warned = []
        session = replay_records(recs, options=SessionOptions(
            pose_source='odom', scan_matching=True, keep_points=True),
            warn=lambda cause, text: warned.append((cause, text)))
        return score(drive, session), warned
    got, warned = run(reset)
    jumps = [text for cause, text in warned if cause == 'odom_jump']
    assert len(jumps) == 1 and 'came back near its origin' in jumps[0], jumps
    given_up = [text for cause, text in warned if cause == 'odom_reset_given_up']
    if found:
        # as the same silence without the reset (its scans are not mapped either)
        control, quiet = run(odometry)
        assert not [cause for cause, _ in quiet if cause.startswith('odom_')
                    and cause != 'odom_gap'], quiet
        assert 'found on the map' in jumps[0] and not given_up, jumps
        assert got['used'] == control['used'] == n - silent, (got['used'], control['used'])
        assert got['rms'] < 0.02, got['rms']
        assert got['walls']['f1'] == control['walls']['f1'] > 0.9, (got['walls'], control['walls'])
    else:
        assert 'searching the map within' in jumps[0] and len(given_up) == 1, warned
        assert got['used'] == k - silent and got['rms'] < 0.02, got
        assert got['walls']['precision'] == 1.0, got['walls']


def test_a_silence_across_a_turn_near_the_odometry_origin_is_no_reset(monkeypatch):
    # A helper audit: the odometry started 0.3 m behind the robot's pose at scan 44 and fell
    # silent for scans 32-43, across a 93 deg turn; no reset. Back near its origin, turned
    # 93 deg, the scan seeing new ground (its odometry's match 0.66 of the scan, under the
    # 0.85 asked), it was taken for a driver restart and searched for: given up, 32 of 1759
    # scans mapped (not judged: all but the silent ones, F1 1.00). A turn alone is now no
    # reset after a silence (only a move of more than ODOM_JUMP[0]).
    import polyline_mapper.session as session_module
    n, j, silent = 150, 44, 12
    drive, odometry = _booted_behind(n, j)
    base = drive.poses
    assert abs(np.angle(np.exp(1j * (base[j, 2] - base[j - silent, 2])))) > 1.5
    quiet = (1000.0 + drive.stamps[j - silent] - 1e-6, 1000.0 + drive.stamps[j] - 1e-6)
    recs = [r for r in flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0),
                                                   odometry=odometry))
            if not (isinstance(r, Odometry) and quiet[0] <= r.stamp < quiet[1])]
    rows, warned = _odom_run(recs)
    assert not {'odom_jump', 'odom_reset_given_up'} & set(warned), warned
    assert len(rows) == n - silent              # every scan but the silent ones
    monkeypatch.setattr(session_module, 'ODOM_RESET_REACH', -1.0)   # no pose near the origin
    before, _ = _odom_run(recs)
    assert np.array_equal(rows, before)


def test_half_rate_odometry_near_its_origin_is_no_heading_reset(monkeypatch):
    # A helper audit: odometry at 5 Hz under 10 Hz scans that started 0.3 m behind the
    # robot's pose at scan 201, just after a simulated 90 deg turn within a scan. Interpolated
    # across the turn, it stepped 31 deg and 0.00 m off its pace near its origin: taken for a
    # reset, re-anchored on the pace twice, 1.8 m RMS (not judged: 0.016 m). A heading jump
    # near the origin is now judged only with the position off the pace too (ODOM_RESET_SHIFT).
    import polyline_mapper.session as session_module
    drive, odometry = _booted_behind(321, 201)
    index = {round(1000.0 + t, 6): i for i, t in enumerate(drive.stamps)}
    recs = [r for r in flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0),
                                                   odometry=odometry))
            if not isinstance(r, Odometry) or index[round(r.stamp, 6)] % 2 == 0]
    rows, warned = _odom_run(recs)
    assert 'odom_jump' not in warned, warned
    monkeypatch.setattr(session_module, 'ODOM_RESET_REACH', -1.0)   # no pose near the origin
    before, _ = _odom_run(recs)
    assert len(rows) > 250 and np.array_equal(rows, before)


def test_a_recording_played_again_follows_its_odometry_back_to_the_start(monkeypatch):
    # ``play --loop`` shifts the stamps forward and starts the recording again: the odometry
    # jumps back to its start (15.6 m here), and so do the scans. Predicted at the last pace,
    # as a reset is, the second pass was mapped 15 m RMS off (walls F1 0.59). Both predictions
    # are matched and the one the scan fits is kept: the odometry here, as before the jump was
    # judged (the second pass 0.057 m RMS, within the drift's 0.3 m at worst).
    import polyline_mapper.session as session_module
    full = make_drive('sim:office', 1)
    drive = dataclasses.replace(full, poses=full.poses[:200], stamps=full.stamps[:200],
                                ranges=full.ranges[:200])
    base = np.asarray(drive.poses, dtype=np.float64)
    odometry = OdometryDrift().apply(base, 3, stamps=drive.stamps)
    again = float(drive.stamps[-1] - drive.stamps[0]) + 0.1
    got = _odometry_run(drive, odometry, again=again)
    assert len(got['odom_jump']) == 1 and 'a recording played again' in got['odom_jump'][0]
    monkeypatch.setattr(session_module, 'ODOM_JUMP', (math.inf, math.inf))
    unjudged = _odometry_run(drive, odometry, again=again)
    assert unjudged['odom_jump'] == []
    rows, before = (np.asarray(g['session'].map_value().trajectory) for g in (got, unjudged))
    assert len(rows) == 2 * len(drive.stamps) and np.array_equal(rows, before)
    first = rows[0, 0] - drive.stamps[0]
    truth = base[np.searchsorted(drive.stamps, rows[200:, 0] - first - again - 1e-6)]
    err = np.hypot(*(rows[200:, 1:3] - truth[:, :2]).T)
    assert np.sqrt(np.mean(err ** 2)) < 0.1, err


def test_a_carried_robot_whose_odometry_follows_keeps_its_odometry(monkeypatch):
    # A helper audit: the robot carried from scan 100's place to scan 200's, its odometry
    # following (scans 100-199 cut out of sim:office). No pace and not the odometry explains
    # the first scan there (trial shares 0.01-0.02), and the pace was taken anyway: 8.0 m RMS
    # (walls F1 0.48) where the odometry alone, as before the jumps were judged, gives 0.45 m.
    # With no pace's match taken the odometry is kept, warned once.
    import polyline_mapper.session as session_module
    full = make_drive('sim:office', 1)
    keep = np.r_[0:100, 200:len(full.stamps)]
    drive = dataclasses.replace(full, poses=full.poses[keep], stamps=full.stamps[:len(keep)],
                                ranges=full.ranges[keep])
    odometry = OdometryDrift().apply(np.asarray(drive.poses, dtype=np.float64), 1,
                                     stamps=drive.stamps)
    got = _odometry_run(drive, odometry)
    assert len(got['odom_jump']) == 1 and 'fits neither' in got['odom_jump'][0], got['odom_jump']
    monkeypatch.setattr(session_module, 'ODOM_JUMP', (math.inf, math.inf))
    before = _odometry_run(drive, odometry)
    rows, old = (np.asarray(g['session'].map_value().trajectory) for g in (got, before))
    assert np.array_equal(rows, old) and got['rms'] == before['rms'] < 0.5, got['rms']
