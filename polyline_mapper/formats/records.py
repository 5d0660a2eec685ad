"""
Plain records read from bags and logs: scans, transforms, odometry, estimates (no ROS types).

A scan carries what a ``sensor_msgs/LaserScan`` carries, in the same precision (ranges and
angles as float32), so a CARMEN log replayed directly and the same log converted to a bag feed
the mapper bit-identical scans. Stamps are seconds (float), frames are tf2 names (no leading
slash), translations metres, rotations unit quaternions (x, y, z, w).
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..scan import beam_angles


@dataclass
class Scan:
    """One laser scan; ``pose`` is set when the source itself knows where the laser was."""

    stamp: float
    """Header stamp, seconds."""
    frame_id: str
    angle_min: float
    """Angle of the first beam, radians (float32 precision)."""
    angle_increment: float
    """Angle between beams, radians (float32 precision)."""
    range_min: float
    range_max: float
    ranges: np.ndarray
    """(B,) float32 metres; NaN / inf / out-of-range readings are dropped later (REP 117)."""
    pose: Optional[np.ndarray] = None
    """(x, y, yaw) of the laser in the fixed frame, metres and radians, or None (look it up)."""
    time_increment: float = 0.0
    """Seconds between beams (LaserScan.time_increment): beam i is taken at stamp + i x this.
    0: all beams at the stamp (the mapper then does no motion compensation)."""
    scan_time: float = 0.0
    """Seconds between scans (LaserScan.scan_time), 0 when unknown."""
    angle_max: Optional[float] = None
    """LaserScan.angle_max, radians, as the message gave it (checked against the beams'
    count, ``scan.check_scan``; CARMEN logs and drives: their last beam's, ``last_angle``);
    None: not known, not checked."""
    intensities: int = 0
    """How many intensities the message had (0, or one per range; checked, ``check_scan``);
    their values are not kept."""

    def angles(self) -> np.ndarray:
        """Return each beam's angle, radians in the laser frame, (B,); ValueError if not finite."""
        return beam_angles(self.angle_min, self.angle_increment, len(self.ranges))

    def message_angle_max(self) -> float:
        """Return the angle_max its LaserScan carries: ``angle_max``, else the last beam's."""
        return (last_angle(self.angle_min, self.angle_increment, len(self.ranges))
                if self.angle_max is None else float(self.angle_max))


@dataclass
class Transform:
    """One stamped transform: the pose of ``child`` in ``parent``."""

    stamp: float
    parent: str
    child: str
    translation: np.ndarray
    """(3,) metres."""
    rotation: np.ndarray
    """(4,) quaternion x, y, z, w."""
    static: bool = False


@dataclass
class Odometry:
    """One odometry reading: the pose of ``child_frame_id`` in ``frame_id``."""

    stamp: float
    frame_id: str
    child_frame_id: str
    translation: np.ndarray
    rotation: np.ndarray


@dataclass
class PoseEstimate:
    """
    A pose estimate: where the robot base is in ``frame_id``, roughly.

    A ``geometry_msgs/PoseWithCovarianceStamped`` on ``/initialpose`` (RViz's "2D Pose
    Estimate"), as AMCL takes it.
    """

    stamp: float
    frame_id: str
    pose: np.ndarray
    """(3,) x, y (m), yaw (rad)."""
    covariance: np.ndarray
    """(3, 3) over x, y, yaw (m^2, rad^2): rows / columns 0, 1 and 5 of the message's 6 x 6."""


@dataclass
class Skipped:
    """A message that could not be decoded or used, with the reason (counted, not fatal)."""

    topic: str
    reason: str


def f32(value) -> float:
    """Round a number to float32 precision, as a LaserScan field stores it."""
    return float(np.float32(value))


def last_angle(angle_min: float, angle_increment: float, beams: int) -> float:
    """Return the angle_max a LaserScan of these fields holds: its last beam's, at float32."""
    return f32(f32(angle_min) + f32(angle_increment) * max(beams - 1, 0))


def clean_frame(name: str) -> str:
    """Return a frame name as tf2 uses it (ROS 1 bags often have a leading slash)."""
    return str(name).lstrip('/')
