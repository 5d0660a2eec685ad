"""Simulated drives written as bags (rosbag2 by BagWriter, ROS 1 by rosbags) and CARMEN logs."""

from dataclasses import dataclass
import gzip

import numpy as np
from polyline_mapper.formats.bag import BagWriter
from polyline_mapper.formats.records import f32, Odometry, Scan
from polyline_mapper.poses import planar_transform, se2_compose
from polyline_mapper.recordings import robot_messages
from polyline_mapper.sim import LaserSpec, World
from polyline_mapper.sim.laser import simulate_scan
from polyline_mapper.sim.world import path_poses

ROOM = np.array([[[0, 0], [8, 0]], [[8, 0], [8, 5]], [[8, 5], [0, 5]], [[0, 5], [0, 0]],
                 [[3, 0], [3, 2]], [[5, 5], [5, 3.5]]], dtype=float)
PATH = [(1, 1), (1.5, 3.8), (4, 2.8), (6.5, 4.2), (6.8, 1.2), (4.2, 1.0)]


@dataclass
class Drive:
    """A simulated drive: base poses (P, 3), laser poses (P, 3), ranges (P, B), stamps (P,)."""

    world: World
    spec: LaserSpec
    base: np.ndarray
    laser: np.ndarray
    ranges: np.ndarray
    stamps: np.ndarray
    mount: np.ndarray

    def scans(self, frame: str = 'laser', with_pose: bool = False) -> list:
        """Return the drive's scans as records (float32 like a LaserScan)."""
        return [Scan(float(t), frame, f32(self.spec.angle_min), f32(self.spec.angle_increment),
                     f32(self.spec.range_min), f32(self.spec.range_max),
                     r.astype(np.float32), p if with_pose else None)
                for t, r, p in zip(self.stamps, self.ranges, self.laser)]


def room_drive(mount=(0.0, 0.0, 0.0), step=0.3, rng=3, beams=271, fov=270.0,
               noise=0.01) -> Drive:
    """Drive through a 8 x 5 m room with two stubs; the laser sits at ``mount`` on the base."""
    world = World(ROOM, path=PATH, name='room')
    spec = LaserSpec(beams=beams, fov=np.deg2rad(fov), range_max=12.0, noise=noise,
                     dropout=0.01)
    base = path_poses(PATH, step)
    mount = np.asarray(mount, dtype=float)
    laser = se2_compose(base, mount[None])
    gen = np.random.default_rng(rng)
    ranges = np.array([simulate_scan(world, p, spec, gen)[0] for p in laser])
    stamps = 5.0 + 0.2 * np.arange(len(base))
    return Drive(world, spec, base, laser, ranges, stamps, mount)


def drive_messages(drive: Drive, mount=None, mount_quaternion=None, tf=True, static=True,
                   odom=True, scan_topic='/scan', tf_until=None, laser_frame='laser'):
    """
    Yield (topic, record, log time) for a drive: /tf_static, /tf odom -> base_link, /odom, scans.

    The messages of ``recordings.robot_messages`` without a map frame, scans logged 1 ms after
    their stamp. ``mount`` (x, y, yaw) and ``mount_quaternion`` override the static transform
    written (default: the true mount), as a misconfigured robot would; ``tf_until`` stops /tf
    after that stamp.
    """
    frames = ('map', 'odom', 'base_link', laser_frame)
    for t, topic, record in robot_messages(
            drive.stamps, drive.laser, drive.scans(laser_frame), drive.mount, frames=frames,
            tf=tf, static=static, odom=odom, tf_until=tf_until):
        if topic == '/tf_static' and (mount is not None or mount_quaternion is not None):
            m = drive.mount if mount is None else mount
            record = [planar_transform(t, 'base_link', laser_frame, m, True, mount_quaternion)]
        if topic == '/scan':
            topic, t = scan_topic, t + 0.001
        yield topic, record, t


def write_bag(path, messages, storage='sqlite3') -> str:
    """Write (topic, record, log time) messages to a new rosbag2; return its path."""
    with BagWriter(str(path), storage) as out:
        for topic, rec, t in messages:
            out.write(topic, rec, t)
    return str(path)


def write_ros1_bag(path, messages, frame_prefix='/', chunk_bytes=None, compression=None) -> str:
    """
    Write the same messages to a ROS 1 bag (frames with a leading slash, as ROS 1 had).

    ``chunk_bytes``: start a new chunk once one holds that many bytes (rosbags: 1 MiB);
    ``compression``: None, 'bz2' or 'lz4' for the chunks.
    """
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import get_types_from_msg, get_typestore, Stores
    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg('geometry_msgs/TransformStamped[] transforms',
                                      'tf2_msgs/msg/TFMessage'))
    t = store.types

    def header(stamp, frame):
        sec = int(np.floor(stamp))
        return t['std_msgs/msg/Header'](0, t['builtin_interfaces/msg/Time'](
            sec, int(round((stamp - sec) * 1e9))), frame_prefix + frame)

    conns = {}
    out = Writer(str(path))
    if compression is not None:
        out.set_compression(Writer.CompressionFormat[compression.upper()])
    if chunk_bytes is not None:
        out.chunk_threshold = int(chunk_bytes)
    with out:
        for topic, rec, stamp in messages:
            if isinstance(rec, Scan):
                typ = 'sensor_msgs/msg/LaserScan'
                n = len(rec.ranges)
                msg = t[typ](header(rec.stamp, rec.frame_id), rec.angle_min,
                             rec.angle_min + rec.angle_increment * (n - 1), rec.angle_increment,
                             rec.time_increment, rec.scan_time, rec.range_min, rec.range_max,
                             rec.ranges,
                             np.zeros(0, np.float32))
            elif isinstance(rec, Odometry):
                typ = 'nav_msgs/msg/Odometry'
                g = 'geometry_msgs/msg/'
                pose = t[g + 'PoseWithCovariance'](t[g + 'Pose'](
                    t[g + 'Point'](*rec.translation), t[g + 'Quaternion'](*rec.rotation)),
                    np.zeros(36))
                zero = t[g + 'Vector3'](0.0, 0.0, 0.0)
                twist = t[g + 'TwistWithCovariance'](t[g + 'Twist'](zero, zero), np.zeros(36))
                msg = t[typ](header(rec.stamp, rec.frame_id), frame_prefix + rec.child_frame_id,
                             pose, twist)
            else:
                typ = 'tf2_msgs/msg/TFMessage'
                g = 'geometry_msgs/msg/'
                msg = t[typ]([t[g + 'TransformStamped'](
                    header(tr.stamp, tr.parent), frame_prefix + tr.child,
                    t[g + 'Transform'](t[g + 'Vector3'](*tr.translation),
                                       t[g + 'Quaternion'](*tr.rotation)))
                    for tr in rec])
            if topic not in conns:
                conns[topic] = out.add_connection(topic, typ, typestore=store)
            out.write(conns[topic], int(round(stamp * 1e9)), store.serialize_ros1(msg, typ))
    return str(path)


def write_carmen(path, drive: Drive, odom_drift=0.0, front_offset=None, garbage_line=None,
                 no_return=81.91) -> str:
    """
    Write a drive as a gzipped CARMEN log of FLASER lines (laser pose, odometry pose, time).

    The drive needs FLASER's beams: 181 over 180 degrees. Odometry is the base pose plus a slow
    drift.
    """
    assert drive.ranges.shape[1] == 181 and np.isclose(drive.spec.fov, np.pi)
    lines = ['# simulated\n']
    if front_offset is not None:
        lines.append(f'PARAM robot_frontlaser_offset {front_offset} host 0\n')
    n = drive.ranges.shape[1]
    for i, (r, lp, bp, t) in enumerate(zip(drive.ranges, drive.laser, drive.base, drive.stamps)):
        odo = bp + odom_drift * i * np.array([1.0, -0.5, 0.01])
        vals = ' '.join(f'{v:.3f}' for v in np.where(np.isfinite(r), r, no_return))
        lp_s = ' '.join(f'{v:.6f}' for v in lp)
        od_s = ' '.join(f'{v:.6f}' for v in odo)
        lines.append(f'FLASER {n} {vals} {lp_s} {od_s} {t:.3f} host {t:.3f}\n')
        if garbage_line is not None and i == garbage_line:
            lines.append('FLASER 181 1.0 2.0 oops\n')
    with gzip.open(path, 'wt') as fh:
        fh.writelines(lines)
    return str(path)
