"""
Laser scans to points: ranges + beam angles + sensor pose -> points in the fixed frame.

Filtering follows REP 117: NaN (erroneous reading), +inf (no return, beyond range) and -inf (too
close) are dropped, and so are readings of 0 (no return at the laser itself) and finite readings
outside [range_min, range_max) - a reading at the maximum range is a no-return on most lasers.
Poses are (x, y, yaw) in metres and radians
(REP 103), of the laser frame in the fixed frame.
"""

from dataclasses import dataclass

import numpy as np

FULL_TURN = 2.0 * np.pi
"""A scan's beams span at most this (radians), within half an increment; more is malformed."""

ANGLE_MAX_SLACK = 1.5
"""``check_scan``: increments the last beam may lie from angle_max (drivers put angle_max at
the last beam, or one increment on at the end of its sector)."""


def beam_angles(angle_min: float, angle_increment: float, count: int) -> np.ndarray:
    """Beam angles (rad) of a LaserScan-like description, shape (count,)."""
    if not np.isfinite(angle_min) or not np.isfinite(angle_increment):
        raise ValueError('angle_min and angle_increment must be finite')
    if angle_increment == 0 and count > 1:
        raise ValueError('angle_increment must not be 0 for a scan with more than one beam')
    return angle_min + angle_increment * np.arange(count)


def valid_ranges(ranges: np.ndarray, range_min: float, range_max: float) -> np.ndarray:
    """
    Mask of usable readings: finite, above 0 and in [range_min, range_max).

    A return at the laser itself is none: drivers that advertise range_min 0 send 0 for "no
    echo" (mapped, each was a point at the laser, along the whole path: an audit).
    """
    r = np.asarray(ranges, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        return np.isfinite(r) & (r > 0.0) & (r >= range_min) & (r < range_max)


def scan_to_points(ranges, angles, pose, range_min: float = 0.0,
                   range_max: float = np.inf) -> np.ndarray:
    """
    Convert one scan to fixed-frame points, dropping unusable readings.

    Parameters
    ----------
    ranges : (B,) array
        Metres; NaN / inf / out-of-range readings are dropped.
    angles : (B,) array
        Radians in the laser frame.
    pose : (3,) array
        (x, y, yaw) of the laser in the fixed frame, metres and radians.
    range_min : float
        Smallest valid range, metres.
    range_max : float
        Valid ranges are below this, metres.

    Returns
    -------
    (M, 2) float64 points, M <= B.

    Raises
    ------
    ValueError
        When ranges and angles differ in length or the pose is not 3 finite numbers.

    """
    return beams_to_points(*usable_beams(ranges, angles, range_min, range_max), pose)


def usable_beams(ranges, angles, range_min: float = 0.0, range_max: float = np.inf) -> tuple:
    """
    Return (ranges, angles) of the usable readings of one scan, each (M,): ``scan_to_points``'s.

    ValueError when ranges and angles differ in length. With ``beams_to_points`` a scan's
    readings are checked once for several poses.
    """
    r = np.asarray(ranges, dtype=np.float64).ravel()
    a = np.asarray(angles, dtype=np.float64).ravel()
    if r.shape != a.shape:
        raise ValueError(f'ranges ({r.size}) and angles ({a.size}) differ in length')
    ok = valid_ranges(r, range_min, range_max) & np.isfinite(a)
    return r[ok], a[ok]


def beams_to_points(ranges: np.ndarray, angles: np.ndarray, pose) -> np.ndarray:
    """
    Return usable readings (``usable_beams``) as (M, 2) points of the laser at ``pose``.

    ValueError when the pose is not 3 finite numbers (x, y, yaw; metres, radians).
    """
    pose = np.asarray(pose, dtype=np.float64).ravel()
    if pose.shape != (3,) or not np.isfinite(pose).all():
        raise ValueError(f'pose must be 3 finite numbers (x, y, yaw), got {pose.tolist()}')
    x, y, yaw = pose
    ang = angles + yaw
    return np.stack([x + ranges * np.cos(ang), y + ranges * np.sin(ang)], axis=1)


class ScanError(ValueError):
    """A scan that cannot be used; ``cause`` names the reason in one word."""

    def __init__(self, cause: str, reason: str):
        super().__init__(reason)
        self.cause = cause


@dataclass
class ScanArrays:
    """One checked scan: ranges (B,) m, beam angles (B,) rad in the laser frame, limits (m)."""

    ranges: np.ndarray
    angles: np.ndarray
    range_min: float
    range_max: float
    stamp: float
    """Seconds (the header stamp)."""
    frame_id: str
    header: object = None
    """The message header, carried to the published map's stamp."""


def check_scan(ranges, angle_min: float, angle_increment: float, range_min: float,
               range_max: float, intensities: int = 0, stamp: float = 0.0, frame_id: str = '',
               header=None, angle_max: float = None) -> ScanArrays:
    """
    Check a LaserScan's content and return it as arrays.

    ``intensities`` is the length of the intensities array (0 or the number of ranges).
    ``angle_max`` (None: not checked): the message's; the last beam, at angle_min + (n - 1) x
    angle_increment, must lie within ``ANGLE_MAX_SLACK`` increments of it, or the ranges do
    not fit the angles (a driver that lists more or fewer ranges than its angles say, or an
    increment of the wrong sign).
    Raises ScanError with cause ``empty_scan``, ``angle_increment`` (not finite, zero, or
    beams spanning more than a full turn), ``angle_min`` (beyond two turns from 0),
    ``angle_max``, ``intensities``, ``range_limits``
    or ``no_valid_ranges`` (every reading NaN, inf or out of range).
    """
    r = np.asarray(ranges, dtype=np.float64).ravel()
    n = r.size
    if n == 0:
        raise ScanError('empty_scan', 'scan has no ranges')
    if not (np.isfinite(angle_min) and np.isfinite(angle_increment)) or (
            angle_increment == 0 and n > 1):
        raise ScanError('angle_increment', f'scan of {n} beams has angle_min {angle_min} and '
                        f'angle_increment {angle_increment} (must be finite and non-zero)')
    if abs(angle_increment) * (n - 1) > FULL_TURN + 0.5 * abs(angle_increment):
        # (a full-circle laser spans 2 pi less one increment, or 2 pi with both ends kept;
        # half an increment more is float32 rounding)
        raise ScanError('angle_increment', f'scan of {n} beams at angle_increment '
                        f'{angle_increment} spans {abs(angle_increment) * (n - 1):.3f} rad, '
                        f'more than a full turn (the ranges do not fit the angles)')
    if abs(angle_min) > 2 * FULL_TURN:
        raise ScanError('angle_min', f'scan has angle_min {angle_min} rad (a beam angle is '
                        f'within two turns: +-{2 * FULL_TURN:.4f})')
    if angle_max is not None and n > 1 and np.isfinite(angle_max):
        last = angle_min + angle_increment * (n - 1)
        if abs(last - angle_max) > ANGLE_MAX_SLACK * abs(angle_increment) + 1e-6:
            raise ScanError('angle_max', f'scan of {n} beams from angle_min {angle_min:.6g} at '
                            f'angle_increment {angle_increment:.6g} ends at {last:.6g} rad, '
                            f'but its angle_max is {angle_max:.6g} (the ranges do not fit the '
                            f'angles)')
    if intensities not in (0, n):
        raise ScanError('intensities', f'scan has {n} ranges but {intensities} intensities')
    if not (np.isfinite(range_min) and range_min >= 0 and not np.isnan(range_max)
            and range_max > range_min):
        raise ScanError('range_limits', f'scan has range_min {range_min} and range_max '
                        f'{range_max} (need 0 <= range_min < range_max)')
    if not valid_ranges(r, range_min, range_max).any():
        raise ScanError('no_valid_ranges', f'none of the {n} ranges is a valid reading (NaN, '
                        f'inf, 0 or outside [{range_min:g}, {range_max:g}))')
    angles = beam_angles(angle_min, angle_increment, n)
    return ScanArrays(r, angles, float(range_min), float(range_max), float(stamp),
                      str(frame_id), header)


SELF_HIT_REACH = 1.5
"""``SelfHits`` watches the readings up to this range (m): the laser sees parts of its robot
(posts, a bumper, a cable, a mast's brace) close by."""
SELF_HIT_TOLERANCE = 0.1
"""A reading is "the same" while it lies within this (m) of the first of its run: twice the
span of a 2-3 cm noise lidar's readings."""
SELF_HIT_MOTION = (3.0, np.radians(90.0))
"""How far (m) the laser must drive, and how far it must turn, while a reading stays the same,
before it is taken for the robot itself. A wall keeps one beam's range while the laser drives
along it (a corridor's side, a round wall followed at a constant distance: an audit's ring
corridor) or turns in a round room's centre; a turn in place changes every wall's range but
that of a round room around the laser, where no driving keeps it. So the run must drive this
far on steps that are mostly a translation, and its heading must span this much with as much
turned in place (``SELF_HIT_SPIN``): the span alone is a ring corridor's, the turns in place
alone add up a corridor's small corrections (an audit of the rule without the span)."""
SELF_HIT_SPIN = 1.0
"""A step whose translation (m) is at most this times its turn (rad) turns in place: a laser
mounted up to 1 m off the axis the robot turns about. One farther off is never found."""
SELF_HIT_STEP = (0.5, np.radians(20.0))
"""A step (m) or turn (rad) from one scan to the next beyond which every run starts over: the
readings were not watched through it (an instant U-turn in a symmetric corridor reads the same
ranges in mirrored beams)."""
SELF_HIT_SCANS = 10
"""... and over at least this many scans."""


class SelfHits:
    """
    Readings of one laser that move with it: parts of the robot it is mounted on.

    A laser that sees a post of its own robot at 0.25 m reads 0.25 m in those beams wherever
    the robot goes, and the mapper draws a wall along the whole path (sim:office, four posts of
    6 deg: 26 -> 764 segments). Such a reading keeps its range (within ``SELF_HIT_TOLERANCE``)
    while the laser drives ``SELF_HIT_MOTION[0]`` and its heading spans
    ``SELF_HIT_MOTION[1]``, turned in place; nothing in the world does. ``add`` follows each
    beam's run of the same reading, vectorised over the beams; a change of the beam count
    starts over.
    """

    def __init__(self):
        self.count = -1
        self._pose = None
        self._driven = 0.0              # the laser's path so far on driving steps (m)
        self._spun = 0.0                # the turns in place so far, in absolute value (rad)
        self._heading = 0.0             # its heading, unwrapped (rad)

    def add(self, ranges, pose, low: float) -> np.ndarray:
        """
        Follow one scan; return which of its beams (B,) bool read the robot itself.

        ``ranges`` (B,) m; ``pose``: the laser's (x, y, yaw) where the scan was placed;
        ``low``: readings below it are not mapped, so not watched.
        """
        with np.errstate(invalid='ignore'):     # (a damaged message's signalling NaNs)
            r = np.asarray(ranges, dtype=np.float64)
        pose = np.asarray(pose, dtype=np.float64)
        if len(r) != self.count:
            self.count = len(r)
            self.ref = np.full(len(r), np.nan)
            self.driven0 = np.zeros(len(r))
            self.spun0 = np.zeros(len(r))
            self.low_heading = np.zeros(len(r))
            self.high_heading = np.zeros(len(r))
            self.scans = np.zeros(len(r), dtype=np.int64)
        elif self._pose is not None:
            step = float(np.hypot(*(pose[:2] - self._pose[:2])))
            turn = float(np.remainder(pose[2] - self._pose[2] + np.pi, 2 * np.pi) - np.pi)
            if step > SELF_HIT_STEP[0] or abs(turn) > SELF_HIT_STEP[1]:
                self.ref[:] = np.nan            # not watched through that motion: start over
            if turn != 0.0 and step <= SELF_HIT_SPIN * abs(turn):
                self._spun += abs(turn)
            else:
                self._driven += step
            self._heading += turn
        self._pose = pose
        with np.errstate(invalid='ignore'):
            watched = np.isfinite(r) & (r >= low) & (r <= SELF_HIT_REACH)
            same = watched & (np.abs(r - self.ref) <= SELF_HIT_TOLERANCE)
        new = ~same
        self.ref[new] = np.where(watched[new], r[new], np.nan)
        self.driven0[new] = self._driven
        self.spun0[new] = self._spun
        self.low_heading[new] = self.high_heading[new] = self._heading
        self.scans[new] = 0
        self.scans += 1
        np.minimum(self.low_heading, self._heading, out=self.low_heading)
        np.maximum(self.high_heading, self._heading, out=self.high_heading)
        return (same & (self.scans >= SELF_HIT_SCANS)
                & (self._driven - self.driven0 >= SELF_HIT_MOTION[0])
                & (self.high_heading - self.low_heading >= SELF_HIT_MOTION[1])
                & (self._spun - self.spun0 >= SELF_HIT_MOTION[1]))


def sectors(angles: np.ndarray, found: np.ndarray) -> list:
    """Return the runs of neighbouring ``found`` beams as (first, last) angles (rad)."""
    idx = np.flatnonzero(found)
    if not len(idx):
        return []
    cut = np.flatnonzero(np.diff(idx) > 1) + 1
    return [(float(angles[g[0]]), float(angles[g[-1]])) for g in np.split(idx, cut)]
