"""Drifting wheel odometry (issue 19's model): the model, and convert --odom-drift."""

from bag_helpers import room_drive, write_carmen
import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.core.index import nearest_distance
from polyline_mapper.formats.bag import BagReader
from polyline_mapper.formats.records import Odometry, Transform
from polyline_mapper.poses import se2_compose, se2_inverse, yaw_from_quaternion
from polyline_mapper.recordings import OdometryDrift
from polyline_mapper.replay import run_replay
from polyline_mapper.session import SessionOptions
import pytest


def test_the_drift_has_the_documented_spread_per_step():
    # 20000 steps of 0.5 m straight ahead: per-step errors as the model says.
    poses = np.column_stack([0.5 * np.arange(20001), np.zeros(20001), np.zeros(20001)])
    drifted = OdometryDrift().apply(poses, 3)
    steps = se2_compose(se2_inverse(drifted[:-1]), drifted[1:])
    assert np.array_equal(drifted[0], poses[0])
    assert np.std(steps[:, 0] - 0.5) == pytest.approx(0.05 * 0.5, rel=0.05)
    assert np.std(steps[:, 1]) == pytest.approx(0.05 * 0.5, rel=0.05)
    assert np.std(steps[:, 2]) == pytest.approx(0.02 + np.deg2rad(1.0) * 0.5, rel=0.05)
    assert np.array_equal(OdometryDrift().apply(poses, 3), drifted)        # seeded
    assert not np.array_equal(OdometryDrift().apply(poses, 4), drifted)


def test_convert_with_odom_drift_writes_a_robot_without_a_localizer(tmp_path, capsys):
    drive = room_drive(beams=181, fov=180.0)
    log = write_carmen(tmp_path / 'room.log.gz', drive)
    bag = tmp_path / 'drifted'
    assert main(['convert', str(log), '-o', str(bag), '--odom-drift', '2', '-q']) == 0
    with BagReader(str(bag), odometry=True) as reader:
        records = list(reader.records())
    frames = {(r.parent, r.child) for r in records if isinstance(r, Transform)}
    assert frames == {('odom', 'base_link'), ('base_link', 'laser')}           # no map frame
    odom = np.array([[r.translation[0], r.translation[1], yaw_from_quaternion(*r.rotation)]
                     for r in records if isinstance(r, Odometry)])
    err = np.hypot(*(odom[:, :2] - drive.base[:, :2]).T)
    assert err[0] < 1e-9 and err[-1] > 0.01                                   # drifts from truth
    # mapped in the odometry frame with the drifted poses: worse than with the true ones
    drifted = run_replay(str(bag), options=SessionOptions(pose_source='odom'))
    true = run_replay(str(log))
    assert drifted.fixed_frame == 'odom' and drifted.used == true.used == len(drive.stamps)
    d_drift = nearest_distance(drifted.points, drive.world.walls)[0].mean()
    d_true = nearest_distance(true.points, drive.world.walls)[0].mean()
    assert d_drift > 2 * d_true


def test_fit_of_a_bag_without_a_map_frame_labels_its_map_with_the_odometry_frame(tmp_path):
    # fit wrote frame_id 'map' whatever frame it registered the scans in: a bag of odometry
    # alone (no map frame) gave a map in 'odom' labelled 'map', and exports (map_server's
    # YAML, GeoJSON) claimed the wrong frame; replay of the same bag said 'odom' (new-user
    # audit). --frame-id still decides when given.
    from polyline_mapper.formats.mapjson import read_map
    log = write_carmen(tmp_path / 'room.log.gz', room_drive(beams=181, fov=180.0))
    bag = tmp_path / 'drifted'
    assert main(['convert', str(log), '-o', str(bag), '--odom-drift', '2', '-q']) == 0
    for extra, frame in (([], 'odom'), (['--pose-source', 'odom', '--laser-mount', '0,0,0'],
                                        'odom'), (['--frame-id', 'world'], 'world')):
        out = tmp_path / f'{frame}{len(extra)}.json'
        assert main(['fit', str(bag), '-o', str(out), '-q'] + extra) == 0
        assert read_map(out).value.frame_id == frame, extra
    out = tmp_path / 'log.json'                      # a CARMEN log's poses are of the map
    assert main(['fit', str(log), '-o', str(out), '-q']) == 0
    assert read_map(out).value.frame_id == 'map'
