"""
Publish a simulated drive as a robot would, for the integration tests and the benchmark.

Messages: LaserScan, /tf (map -> odom -> base_link), a static laser mount on /tf_static, and
nav_msgs/Odometry.

The drive's poses are laser poses in the world (= map) frame. With a mount (laser in base_link,
x, y, yaw, optionally upside down) the base pose is the laser pose composed with the inverse
mount; ``map_to_odom`` offsets the odometry frame, so the node must chain all three edges to
get the map right. An upside-down laser sweeps clockwise: its scan message lists the same beams
in reverse order (the simulator's beam fan is symmetric about the laser's x axis).
"""

import math

from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import LaserScan

from ..poses import quaternion_from_yaw


def compose(a, b) -> np.ndarray:
    """Return planar pose a * b (b given in a's frame), as (x, y, yaw)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def inverse(a) -> np.ndarray:
    """Return the inverse of planar pose a."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]])


def to_time(stamp: float):
    """Return float seconds as builtin_interfaces/Time."""
    from builtin_interfaces.msg import Time
    sec = math.floor(stamp)
    return Time(sec=int(sec), nanosec=int(round((stamp - sec) * 1e9)) % 1000000000)


def _transform(parent: str, child: str, stamp: float, pose, quat=None) -> TransformStamped:
    ts = TransformStamped()
    ts.header.frame_id = parent
    ts.header.stamp = to_time(stamp)
    ts.child_frame_id = child
    ts.transform.translation.x = float(pose[0])
    ts.transform.translation.y = float(pose[1])
    q = quaternion_from_yaw(pose[2]) if quat is None else quat
    r = ts.transform.rotation
    r.x, r.y, r.z, r.w = (float(v) for v in q)
    return ts


class DriveMessages:
    """Messages of a SimulatedDrive: scan i at stamp t, the transforms and odometry for it."""

    def __init__(self, drive, mount=(0.0, 0.0, 0.0), upside_down: bool = False,
                 map_to_odom=(0.0, 0.0, 0.0), laser_frame: str = 'laser',
                 base_frame: str = 'base_link', odom_frame: str = 'odom',
                 map_frame: str = 'map'):
        self.drive = drive
        self.mount = np.asarray(mount, dtype=float)
        self.upside_down = upside_down
        self.map_to_odom = np.asarray(map_to_odom, dtype=float)
        self.frames = (map_frame, odom_frame, base_frame, laser_frame)
        spec = drive.spec
        if upside_down and not np.isclose(spec.angle_min + spec.angles()[-1], 0.0):
            raise ValueError('an upside-down laser needs a beam fan symmetric about x')

    def __len__(self) -> int:
        return len(self.drive.poses)

    def base_pose(self, i: int) -> np.ndarray:
        """Return the base pose (x, y, yaw) in the map frame for scan i."""
        return compose(self.drive.poses[i], inverse(self.mount))

    def scan(self, i: int, stamp: float, frame_id: str = None) -> LaserScan:
        """Return scan i as a LaserScan stamped ``stamp`` (s)."""
        spec = self.drive.spec
        msg = LaserScan()
        msg.header.frame_id = self.frames[3] if frame_id is None else frame_id
        msg.header.stamp = to_time(stamp)
        msg.angle_min = float(spec.angle_min)
        msg.angle_max = float(spec.angles()[-1])
        msg.angle_increment = float(spec.angle_increment)
        msg.range_min = float(spec.range_min)
        msg.range_max = float(spec.range_max)
        ranges = self.drive.ranges[i]
        msg.ranges = (ranges[::-1] if self.upside_down else ranges).astype(np.float32)
        return msg

    def static_mount(self) -> TransformStamped:
        """Return the base_link -> laser mount (stamp 0, for /tf_static)."""
        quat = None
        if self.upside_down:
            h = 0.5 * self.mount[2]
            quat = (math.cos(h), math.sin(h), 0.0, 0.0)       # yaw, then roll 180 deg
        return _transform(self.frames[2], self.frames[3], 0.0, self.mount, quat)

    def transforms(self, i: int, stamp: float) -> list:
        """Return map -> odom and odom -> base_link for scan i, stamped ``stamp``."""
        odom_base = compose(inverse(self.map_to_odom), self.base_pose(i))
        return [_transform(self.frames[0], self.frames[1], stamp, self.map_to_odom),
                _transform(self.frames[1], self.frames[2], stamp, odom_base)]

    def odometry(self, i: int, stamp: float) -> Odometry:
        """Return the base pose of scan i in the odometry frame as nav_msgs/Odometry."""
        pose = compose(inverse(self.map_to_odom), self.base_pose(i))
        msg = Odometry()
        msg.header.frame_id = self.frames[1]
        msg.header.stamp = to_time(stamp)
        msg.child_frame_id = self.frames[2]
        msg.pose.pose.position.x = float(pose[0])
        msg.pose.pose.position.y = float(pose[1])
        q = msg.pose.pose.orientation
        q.x, q.y, q.z, q.w = (float(v) for v in quaternion_from_yaw(pose[2]))
        return msg
