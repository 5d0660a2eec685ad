"""
A pose estimate (``MappingSession.set_pose``; the node's ``initialpose``): start or recover.

What RViz's "2D Pose Estimate" gives AMCL: where the robot is, roughly. On a saved map whose
odometry starts elsewhere, the first match lands on a wrong place and keeps to it; after a gap
in the scans the search may give up for good. An estimate with its spread is searched for
(as after a gap: several keyframes, one place must explain them), and nothing is mapped
until it is found.
"""

import importlib
import json
import sys

from bag_helpers import write_bag
from conftest import radish_log, REPO, saved_office_map
import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.core.geometry import se2_compose, se2_inverse
from polyline_mapper.formats.mapjson import read_map
from polyline_mapper.formats.records import PoseEstimate, Scan
from polyline_mapper.recordings import make_drive
from polyline_mapper.session import MappingSession, SessionOptions
import pytest
from test_imperfect_poses import records, score
from test_localization import drifted_messages, records_of, true_base
from test_scan_gaps import OFFICE, with_gap

ODOM_ORIGIN = (1.5, -0.8, 0.4)
"""Where the drifted odometry's frame starts in the map: 1.7 m and 0.4 rad off."""
AT = 40
"""The scan before which the estimate is given."""


@pytest.fixture(scope='module')
def office():
    """Return the drive of ``sim:office`` (as replay opens it) and its map from true poses."""
    return make_drive('sim:office')


@pytest.fixture(scope='module')
def saved_file(office, office_map_file, tmp_path_factory):
    """Return the path of the office mapped with true poses (replay)."""
    return saved_office_map(office_map_file, tmp_path_factory.mktemp('estimate'))


@pytest.fixture(scope='module')
def saved(saved_file):
    """Return the office map, as read back from MAP.json."""
    return read_map(saved_file)


@pytest.fixture(scope='module')
def gap_office():
    """Return test_scan_gaps' office drive (10 Hz, turns in place) and its scan-only records."""
    drive = make_drive(OFFICE, 1)
    return drive, records(drive, scans_only=True)


def localize(saved, office, estimate=None, spread=(0.0, 0.0), mapping=False, initial=None):
    """Localize the drifted drive on ``saved`` (odometry elsewhere); estimate before scan AT."""
    warned = []
    session = MappingSession(None, SessionOptions(keep_points=True, mapping=mapping,
                                                  pose_source='odom'),
                             warn=lambda cause, text: warned.append((cause, text)))
    session.load_map(saved.value, initial)
    n = 0
    for record in records_of(drifted_messages(office, 1, odom_origin=ODOM_ORIGIN)):
        if isinstance(record, Scan):
            if n == AT and estimate is not None:
                session.set_pose(estimate, spread)
            n += 1
        session.add(record)
        session.step()
    session.flush()
    return session, warned


def errors(session, office) -> np.ndarray:
    """Per scan: the distance (m) of the trajectory's base pose from the true one."""
    trajectory = session.map_value().trajectory
    assert len(trajectory) == len(office.poses)
    return np.hypot(*(trajectory[:, 1:3] - true_base(office)[:, :2]).T)


@pytest.mark.parametrize('offset, spread, outcome', [
    ((0.4, -0.3, 0.25), (1.5, 0.75), 'found near the estimate'),    # a click, searched for
    ((0.1, 0.05, 0.05), (0.0, 0.0), 'matched'),                      # exact: matched from it
])
def test_an_estimate_moves_a_robot_matched_to_the_wrong_place(saved, office, offset, spread,
                                                              outcome):
    # Without it the odometry's start, 1.7 m and 0.4 rad off, is matched onto a wrong place
    # and the robot stays there: 0.78 m mean error over the whole drive. (Too near the right
    # place for the wrong_start warning: 11 % of the first scans' beams pass through the
    # saved walls, median; the warning takes 30 %.)
    session, _ = localize(saved, office)
    assert errors(session, office).mean() > 0.5
    estimate = true_base(office)[AT] + np.asarray(offset)
    session, warned = localize(saved, office, estimate, spread)
    err = errors(session, office)
    assert err[:AT].mean() > 0.5
    assert np.sqrt(np.mean(err[AT + 10:] ** 2)) < 0.05 and err[AT + 10:].max() < 0.1, err
    assert session.matches[outcome] >= 1 and not session.lost
    assert not [cause for cause, _ in warned if cause.startswith('pose_estimate')]
    value = session.map_value()                # localization only: the map is the saved one
    assert np.array_equal(value.segments, saved.value.segments)


RVIZ_SPREAD = 3.0 * np.sqrt([0.25, 0.0685])
"""The window of RViz's default estimate covariance (0.5 m, 0.26 rad; POSE_ESTIMATE_SIGMAS)."""


def localized_with(saved, office, estimates: dict) -> tuple:
    """Localize drift seed 0 on ``saved``, mapping off; ``estimates``: {scan: (pose, spread)}."""
    warned = []
    session = MappingSession(None, SessionOptions(keep_points=True, mapping=False),
                             warn=lambda cause, text: warned.append((cause, text)))
    session.load_map(saved.value)
    n = 0
    for record in records_of(drifted_messages(office, 0)):
        if isinstance(record, Scan):
            if n in estimates:
                session.set_pose(*estimates[n])
            n += 1
        session.add(record)
        session.step()
    session.flush()
    return session, warned


@pytest.mark.parametrize('at', [60, 65, 260])
def test_a_right_estimate_given_while_localized_keeps_the_robot_localized(saved, office, at):
    # A localization audit: RViz's default estimate (0.5 m and 0.26 rad standard deviations)
    # at the true pose of a robot localized in the office's corridor: places 1.5 m (scan 60)
    # or 0.6 m (65) apart explained the scans alike over all 8 keyframes, scan matching gave
    # up for good and no later scan was used. At that last search the estimate now prefers
    # the place nearest it, when the scans before it were matched there; the scans until
    # then are still searched for (11 at scans 60 and 65, 12 at 260, as before).
    truth = true_base(office)
    session, warned = localized_with(saved, office, {at: (truth[at], RVIZ_SPREAD)})
    trajectory = session.map_value().trajectory
    assert len(trajectory) >= len(office.poses) - 12
    index = np.searchsorted(1000.0 + np.asarray(office.stamps), trajectory[:, 0] - 1e-6)
    err = np.hypot(*(trajectory[:, 1:3] - truth[index, :2]).T)
    assert np.sqrt(np.mean(err ** 2)) < 0.02 and err.max() < 0.06, err
    assert session.matches['found near the estimate'] == 1 and not session.lost
    assert 'pose_estimate_given_up' not in [cause for cause, _ in warned], warned


@pytest.mark.parametrize('off, found', [(0.9, True), (0.6, False)])
def test_a_right_estimate_does_not_lock_a_robot_tracked_at_a_wrong_place(
        saved, office, off, found):
    # An audit of the rule above as first written (the tracked place taken at the first
    # search): tracked 1.47 m ahead of the truth in the corridor (placed there at scan 55),
    # RViz's default estimate 0.9 or 0.6 m off the truth at scan 60 locked the robot at the
    # wrong place, unwarned. As before, the later keyframes find the truth (0.9) or the
    # search gives up and says so (0.6): the tracked place never overrides the estimate.
    truth = true_base(office)
    session, warned = localized_with(saved, office, {
        55: (truth[55] + [1.47, 0.0, 0.0], (0.05, 0.05)),
        60: (truth[60] + [off, 0.0, 0.0], RVIZ_SPREAD)})
    loc = session.localization
    if found:
        assert not session.lost and np.hypot(*(loc.pose[:2] - truth[-1, :2])) < 0.05
    else:
        assert session.lost and 'pose_estimate_given_up' in [c for c, _ in warned]


def test_a_wrong_estimate_maps_nothing_and_says_so(saved, office):
    # An estimate 2.5 m from the robot, searched within 1 m: no place near it explains the
    # scans. Mapping on: nothing may be mapped at a guessed pose; the map stays as it was.
    estimate = se2_compose(true_base(office)[AT], np.array([0.0, 2.5, 0.0]))
    session, warned = localize(saved, office, estimate, (1.0, 0.3), mapping=True)
    causes = [cause for cause, _ in warned if cause.startswith('pose_estimate')]
    assert causes == ['pose_estimate', 'pose_estimate_given_up'], warned
    assert 'near the pose estimate' in warned[[c for c, _ in warned].index('pose_estimate')][1]
    assert session.used == AT and session.matches['found near the estimate'] == 0
    assert session.lost                         # /diagnostics says so (mapping_status WARN)
    assert session.skipped['not mapped: lost'] == len(office.poses) - AT
    # The pose published meanwhile (the prediction) said 0.1 m and 0.05 rad while it was 2.5 to
    # 8 m off (a localization audit); given up, it says the robot is not localized.
    loc = session.localization
    assert not loc.matched and np.hypot(*(loc.pose[:2] - true_base(office)[-1, :2])) > 2.0
    assert np.sqrt(np.diag(loc.covariance)) == pytest.approx([3.0, 3.0, np.pi], rel=0.05)
    before, _ = localize(saved, office, mapping=True)
    assert len(session.map_value().segments) <= len(before.map_value().segments) + 5


def test_an_estimate_brings_back_a_scan_only_session_that_gave_up(gap_office):
    # 5 s without scans: the search gives up and no later scan is mapped (test_scan_gaps).
    # When the robot is back on mapped ground (scan 1050, the corridor it explored first),
    # an estimate 0.3 m and 0.2 rad off, spread 1 m / 0.5 rad, brings mapping back: every
    # later scan is used, every pose within 10 cm, every wall right.
    drive, scans = gap_office
    scans = with_gap(scans, 500, 50)
    session = MappingSession(None, SessionOptions(pose_source='scan', keep_points=True))
    origin = np.asarray(drive.poses[0])
    for i, scan in enumerate(scans):
        if i == 1050:
            assert session.used == 500 and session.skipped['not mapped: lost'] == 500
            truth = se2_compose(se2_inverse(origin), np.asarray(drive.poses[i]))
            session.set_pose(se2_compose(truth, np.array([0.3, -0.1, 0.2])), (1.0, 0.5))
        session.add(scan)
        session.step()
    session.flush()
    s = score(drive, session, origin)
    assert session.matches['found near the estimate'] == 1
    assert session.used >= 500 + len(scans) - 1050 - 5, session.used
    assert s['err'].max() < 0.1 and s['walls']['precision'] == 1.0, (s['err'].max(), s['walls'])
    late = s['index'] >= 1050
    assert np.sqrt(np.mean(s['err'][late] ** 2)) < 0.05


@pytest.mark.parametrize('options, pose, spread, words', [
    ({}, (0.0, 0.0, 0.0), (1.0, 0.5), 'needs scan matching'),
    ({'scan_matching': True}, (0.0, float('nan'), 0.0), (1.0, 0.5), 'pose must be 3 finite'),
    ({'scan_matching': True}, (0.0, 0.0), (1.0, 0.5), 'pose must be 3 finite'),
    ({'scan_matching': True}, (0.0, 0.0, 0.0), (-1.0, 0.5), 'spread must be 2 finite'),
    ({'scan_matching': True}, (0.0, 0.0, 0.0), (float('inf'), 0.5), 'spread must be 2 finite'),
])
def test_a_bad_estimate_is_refused_in_one_line_and_changes_nothing(office, options, pose,
                                                                   spread, words):
    records = records_of(drifted_messages(office, 1), scans=60)
    first = [k for k, r in enumerate(records) if isinstance(r, Scan)][30]
    sessions = [MappingSession(None, SessionOptions(keep_points=True, **options))
                for _ in range(2)]
    for k, record in enumerate(records):
        if k == first:                          # at scan 30 the second session refuses
            with pytest.raises(ValueError, match=words) as info:
                sessions[1].set_pose(pose, spread)
            assert '\n' not in str(info.value)
        for session in sessions:
            session.add(record)
            session.step()
    values = [session.map_value() for session in sessions]
    assert len(values[0].trajectory) == 60
    assert np.array_equal(values[0].trajectory, values[1].trajectory)
    assert np.array_equal(values[0].segments, values[1].segments)


def test_reset_drops_an_estimate_not_yet_used(saved, office):
    # A reset between the estimate and the next scan goes back to the saved map and its
    # initial pose: no search near the dropped estimate.
    session = MappingSession(None, SessionOptions(keep_points=True, mapping=False,
                                                  pose_source='odom'))
    session.load_map(saved.value, true_base(office)[0])
    records = records_of(drifted_messages(office, 1), scans=20)
    session.set_pose((3.0, 2.0, 1.0), (1.5, 0.75))
    session.reset()
    for record in records:
        session.add(record)
        session.step()
    assert not [k for k in session.matches if 'estimate' in k], session.matches
    assert session.matches['matched'] >= 19 and not session.lost


RVIZ = np.diag([0.25, 0.25, 0.06853892326654787])
"""The covariance RViz's "2D Pose Estimate" gives (0.5 m, 0.26 rad standard deviations)."""


def test_estimates_in_a_bag_are_taken_in_their_turn_as_the_node_takes_them(
        saved_file, office, tmp_path):
    # A recording of a robot whose operator gave a pose estimate (/initialpose) before scan
    # AT: one in the odometry frame (skipped: counted, warned), then one in the map 0.3 m off.
    # Replayed on the saved map, it places the robot as the node does; without it, 0.78 m off.
    messages = drifted_messages(office, 1, odom_origin=ODOM_ORIGIN)
    at = [k for k, m in enumerate(messages) if m[0] == '/scan'][AT]
    t = messages[at][2]
    estimate = true_base(office)[AT] + np.array([0.3, -0.2, 0.15])
    messages[at:at] = [('/initialpose', PoseEstimate(t, frame, estimate, RVIZ), t)
                       for frame in ('odom', 'map')]
    bag = write_bag(tmp_path / 'estimated', messages)
    out = tmp_path / 'out.json'
    assert main(['replay', bag, '--map', str(saved_file), '--no-mapping', '-o', str(out),
                 '-q']) == 0
    data = json.loads(out.read_text())
    trajectory = np.array(data['trajectory'])
    err = np.hypot(*(trajectory[:, 1:3] - true_base(office)[:, :2]).T)
    assert err[:AT].mean() > 0.5
    assert np.sqrt(np.mean(err[AT + 10:] ** 2)) < 0.05, err
    assert data['stats']['skipped'] == {'pose estimate': 1}
    assert data['stats']['scan_matching']['found near the estimate'] == 1


def test_on_the_intel_log_an_estimate_localizes_as_a_true_start():
    # Real data (benchmarks/pose_estimate.py): Intel's map from the corrected poses, the log
    # localized on it with drifting odometry whose frame starts 2.5 m and 0.6 rad off. With
    # nothing given the first scans are matched onto wrong places (6 m RMS until 2026-12-01;
    # 0.25 m since: the chords of scans put under half on the map and the chords are no longer
    # kept, so those wrong places do not carry on, and the map takes the track back). An
    # estimate 0.3-1.0 m
    # and 0.1-0.5 rad off before scan 10 localizes as a true start does (3.4 cm). Tracked at
    # constant velocity instead of by the odometry, the scans after the estimate (0.5 m apart
    # in this log) were never found: 900 of 910 not mapped.
    sys.path.insert(0, str(REPO / 'benchmarks'))
    bench = importlib.import_module('pose_estimate')
    rows = {r['case']: r for r in bench.one_log('intel', str(radish_log('intel-corrected.log.gz')),
                                                10)}
    # Localizing on a wrong place is warned of once (33 % of the first 10 scans' beams pass
    # through the saved walls, median; 40 % before 2026-12-01), the true start not (3 %); an
    # estimate after the warning is not warned of again.
    reference = rows['true start']['rms_m']
    assert rows['no start']['rms_m'] > 5 * reference
    assert rows['no start']['warnings']['wrong_start'] == 1
    assert 'wrong_start' not in rows['true start']['warnings']
    # and it stays said (the node's /diagnostics WARN) until a pose is given: a node audit saw
    # a robot tracked 6 m off with /diagnostics OK after the one warning
    assert rows['no start']['wrong_start_at_end'] and not rows['true start']['wrong_start_at_end']
    assert reference < 0.05
    estimates = [r for case, r in rows.items() if case.startswith('estimate')]
    assert len(estimates) == 3
    for r in estimates:
        assert r['rms_m'] <= reference + 0.005 and r['not_mapped'] <= 5, r
        assert r['matches']['found near the estimate'] == 1
        assert r['warnings']['wrong_start'] == 1 and not r['wrong_start_at_end']


def test_a_right_start_is_not_warned_of(saved, office):
    # The true initial pose: no beam of the first scans passes through the saved walls, and
    # no wrong_start warning (the Intel test below has a wrong start warned of).
    session, warned = localize(saved, office, initial=true_base(office)[0])
    assert np.sqrt(np.mean(errors(session, office) ** 2)) < 0.05
    assert 'wrong_start' not in [cause for cause, _ in warned]


def _estimate_msg(frame='map', q=(0.0, 0.0, 0.0, 1.0), cov=RVIZ):
    """Return a geometry_msgs/PoseWithCovarianceStamped as RViz sends it (for the converter)."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = frame
    msg.pose.pose.position.x, msg.pose.pose.position.y = 1.0, 2.0
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = q
    full = np.zeros((6, 6))
    full[np.ix_((0, 1, 5), (0, 1, 5))] = cov
    msg.pose.covariance = full.reshape(-1)
    return msg


@pytest.mark.parametrize('msg, words', [
    ({'frame': 'odom'}, "in frame 'odom': it must be in 'map'"),
    ({'q': (0.0, 0.0, 0.0, 0.0)},         # the numbers as numbers, not np.float64(nan)
     'pose [1.0, 2.0, nan] is not 3 finite numbers (x, y, yaw; no yaw from a quaternion that '
     'is not normalised)'),
    ({'q': (0.0, 0.0, float('nan'), 1.0)}, 'not normalised'),
    ({'cov': np.diag([0.25, float('nan'), 0.07])}, 'no finite variances'),
    ({'cov': np.diag([0.25, 0.25, -0.07])}, 'no finite variances'),
])
def test_a_bad_estimate_message_is_a_counted_skip_that_changes_nothing(saved, office, msg,
                                                                       words):
    pytest.importorskip('geometry_msgs.msg', reason='the ROS 2 messages are not installed')
    from polyline_mapper.ros.messages import pose_estimate_from_msg
    record = pose_estimate_from_msg(_estimate_msg(**msg))
    records = records_of(drifted_messages(office, 1), scans=40)
    first = [k for k, r in enumerate(records) if isinstance(r, Scan)][20]
    runs = []
    for bad in (False, True):
        warned = []
        session = MappingSession(None, SessionOptions(keep_points=True, mapping=False),
                                 warn=lambda cause, text: warned.append((cause, text)))
        session.load_map(saved.value, true_base(office)[0])
        for k, r in enumerate(records):
            if bad and k == first:
                session.add(record)
            session.add(r)
            session.step()
        runs.append((session, warned))
    (good, _), (session, warned) = runs
    assert session.stats()['skipped'] == {'pose estimate': 1}
    skips = [text for cause, text in warned if cause == 'initial_pose']
    assert len(skips) == 1 and words in skips[0] and '\n' not in skips[0], warned
    assert np.array_equal(good.map_value().trajectory, session.map_value().trajectory)
