"""
CARMEN log reader (FLASER and ROBOTLASER1 records), gzip or plain text.

Conventions (see the Radish logs' notes): FLASER carries ``n`` ranges, then the corrected laser
pose x, y, theta, the odometry pose, and time stamps; beam i is at -pi/2 + i*pi/n for even n and
-pi/2 + i*pi/(n-1) for odd n, relative to theta. ROBOTLASER1 states its start angle, angular
resolution and maximum range, and the laser pose after the remissions.

No-return readings: FLASER does not state the sensor's maximum range, and logs encode a missing
echo as that maximum (50, 51.2, 81.83, 81.91 m ...). The largest reading of a log that occurs more
than once is taken as that code, when at most 1 in 1000 readings lie above it (single glitches,
dropped with it), and every reading >= 0.99 x it is dropped. ROBOTLASER1 records
use their own maximum range.

For bags and the replay, a log also gives its laser mount (``robot_frontlaser_offset``, metres
ahead of the robot centre, for FLASER; the laser pose relative to the robot pose for
ROBOTLASER1), each record's odometry pose (FLASER ``odom_*``, ROBOTLASER1 robot pose), and scans
in LaserScan form (``CarmenLog.scans``) with stamps from the log times when they increase.
"""

from dataclasses import dataclass, field
import gzip
import os
import stat
from typing import Optional
import zlib

import numpy as np

from .points import MAX_COORDINATE
from .records import f32, last_angle, Scan
from ..scan import scan_to_points


@dataclass
class LaserRecord:
    """One scan: ranges (m), beam angles (rad, laser frame), laser pose (x, y, yaw), stamp (s)."""

    ranges: np.ndarray
    angles: np.ndarray
    pose: np.ndarray
    stamp: float
    range_max: float = np.inf
    odom: Optional[np.ndarray] = None
    """(x, y, yaw) of the robot by odometry (FLASER odom_*, ROBOTLASER1 robot pose)."""
    angle_min: float = -np.pi / 2
    """First beam angle (rad); ``angles`` is angle_min + i * angle_increment."""
    angle_increment: float = np.pi / 180


@dataclass
class CarmenLog:
    """The laser records of a log and the count of lines that could not be used."""

    records: list
    skipped: int = 0
    skipped_examples: list = field(default_factory=list)
    no_return: float = np.inf
    laser_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """(x, y, yaw) of the laser on the robot, metres and radians."""
    bad_readings: int = 0
    """Readings that are no range (negative or NaN): dropped as the mapper drops them."""

    def usable_range(self, rec: LaserRecord) -> float:
        """Return the range (m) at or beyond which readings of ``rec`` are no-returns."""
        return min(rec.range_max, self.no_return * 0.99, MAX_RANGE)

    def stamps(self, period: float = 1.0) -> tuple:
        """
        Return one stamp per scan, seconds, and whether they had to be made up.

        The log times are used when they strictly increase (shifted to start at 1 s when the
        first is not positive); otherwise (zero, repeated or shuffled times, as in several
        Radish logs) the stamps are 1 s + i * ``period``.
        """
        t = np.array([r.stamp for r in self.records], dtype=np.float64)
        if len(t) and np.isfinite(t).all() and np.all(np.diff(t) > 0):
            return (t if t[0] > 0 else t - t[0] + 1.0), False
        made = 1.0 + period * np.arange(len(t))
        if len(t) > 1 and not (period >= MIN_PERIOD and made[-1] < ROS_TIME_END):
            raise ValueError(f'period {period:g} s: the log times do not increase, and stamps '
                             f'made up {period:g} s apart must be at least {MIN_PERIOD:g} s apart '
                             f'and end before {ROS_TIME_END:g} s (a ROS time; the last would be '
                             f'{made[-1]:g} s)')
        return made, True

    def scans(self, stamps=None, frame_id: str = 'laser', with_pose: bool = True) -> list:
        """
        Return the records as LaserScan-like ``Scan``s (float32 fields), with their laser pose.

        ``stamps`` (R,) seconds default to ``stamps()``. ``range_max`` is the no-return limit.
        """
        stamps = self.stamps()[0] if stamps is None else stamps
        with np.errstate(over='ignore'):    # readings beyond float32 become inf: no return
            return [Scan(float(t), frame_id, f32(r.angle_min), f32(r.angle_increment), 0.0,
                         f32(self.usable_range(r)), np.asarray(r.ranges, dtype=np.float32),
                         np.asarray(r.pose, dtype=np.float64) if with_pose else None,
                         angle_max=last_angle(r.angle_min, r.angle_increment, len(r.ranges)))
                    for r, t in zip(self.records, stamps)]

    def points(self, range_max: float = None, progress=None) -> np.ndarray:
        """
        Register every scan with its (corrected) pose into one (N, 2) point set, metres.

        ``range_max`` additionally limits the usable range (m).
        """
        return self.beams(range_max, progress)[0]

    def beams(self, range_max: float = None, progress=None) -> tuple:
        """
        Return ``(points, origins)``: ``points()`` and the laser position of each, (N, 2) m.

        The origin of a point is the (corrected) pose of the record it comes from.
        """
        out, counts = [], []
        recs = self.records if progress is None else progress(self.records)
        for rec in recs:
            top = self.usable_range(rec)
            if range_max is not None:
                top = min(top, range_max)
            out.append(scan_to_points(rec.ranges, rec.angles, rec.pose, 0.0, top))
            counts.append(len(out[-1]))
        points = np.concatenate(out) if out else np.zeros((0, 2))
        poses = np.array([rec.pose[:2] for rec in self.records], dtype=np.float64).reshape(-1, 2)
        return points, np.repeat(poses, counts, axis=0)


def _flaser_step(n: int) -> float:
    return np.pi / n if n % 2 == 0 else np.pi / max(n - 1, 1)


def _check_pose(pose: np.ndarray) -> None:
    """Refuse a record's laser pose that is not finite or lies beyond MAX_COORDINATE metres."""
    if not np.isfinite(pose).all():
        raise ValueError('non-finite pose')
    if np.abs(pose[:2]).max() > MAX_COORDINATE:
        raise ValueError(f'pose beyond +-{MAX_COORDINATE:.0e} m')


def _parse_flaser(tok: list) -> LaserRecord:
    n = int(tok[1])
    if n < 1 or not n + 9 <= len(tok) <= n + 11:     # the host and logger time are optional
        raise ValueError(f'FLASER announces {n} readings but the line has {len(tok)} fields')
    vals = np.array(tok[2:n + 9], dtype=np.float64)
    ranges, pose, odom, stamp = vals[:n], vals[n:n + 3], vals[n + 3:n + 6], vals[n + 6]
    _check_pose(pose)
    step = _flaser_step(n)
    return LaserRecord(ranges, -np.pi / 2 + np.arange(n) * step, pose, float(stamp),
                       odom=odom if np.isfinite(odom).all() else pose.copy(),
                       angle_min=-np.pi / 2, angle_increment=step)


def _parse_robotlaser(tok: list) -> LaserRecord:
    if len(tok) < 10:
        raise ValueError('ROBOTLASER1 record is shorter than its counts say')
    start, _, res, rmax = (float(v) for v in tok[2:6])
    n = int(tok[8])
    m = int(tok[9 + n])
    base = 10 + n + m
    if n < 1 or m < 0 or len(tok) < base + 12:
        raise ValueError('ROBOTLASER1 record is shorter than its counts say')
    ranges = np.array(tok[9:9 + n], dtype=np.float64)
    pose = np.array(tok[base:base + 3], dtype=np.float64)
    robot = np.array(tok[base + 3:base + 6], dtype=np.float64)
    stamp = float(tok[base + 11])
    _check_pose(pose)
    return LaserRecord(ranges, start + res * np.arange(n), pose, stamp, rmax,
                       odom=robot if np.isfinite(robot).all() else pose.copy(),
                       angle_min=start, angle_increment=res)


def _offset(rec: Optional[LaserRecord], front: float) -> np.ndarray:
    """Laser mount on the robot: from a ROBOTLASER1's two poses, else the front-laser offset."""
    if rec is None:
        return np.array([front, 0.0, 0.0])
    d = rec.pose[:2] - rec.odom[:2]
    c, s = np.cos(rec.odom[2]), np.sin(rec.odom[2])
    yaw = np.arctan2(np.sin(rec.pose[2] - rec.odom[2]), np.cos(rec.pose[2] - rec.odom[2]))
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], yaw])


MAX_LINE_BYTES = 2 ** 20
"""Longest log line read (1 MiB: a 100k-beam laser line); longer lines are skipped as
malformed without being held in memory."""


def _lines(fh, limit: int = MAX_LINE_BYTES):
    """
    Yield ``(bytes line, over_long)`` of a binary file, reading at most ``limit`` bytes at once.

    An over-long line is yielded once as its first ``limit`` bytes with ``over_long`` True;
    the rest of it is read and dropped, so memory stays bounded whatever the file holds.
    """
    while True:
        line = fh.readline(limit)
        if not line:
            return
        if len(line) < limit or line.endswith(b'\n'):
            yield line, False
            continue
        while True:                     # drop the rest of the line
            rest = fh.readline(limit)
            if not rest or rest.endswith(b'\n'):
                break
        yield line, True


MAX_RANGE = 1000.0
"""Metres: a reading beyond is no range a 2D laser measures (they reach 80-250 m), so no point
and no candidate for the no-return code (one bogus value repeated, 1e300, hid the code)."""
NO_RETURN_GLITCHES = 1e-3
"""Share of a log's readings that may lie above its no-return code as single glitches."""
MIN_PERIOD = 1e-6
"""Seconds: made-up stamps closer than this would be one (maps and bags keep 1 us / 1 ns)."""
ROS_TIME_END = 2.0 ** 31
"""Seconds: builtin_interfaces/Time holds its seconds in an int32."""


def read_carmen(path: str) -> CarmenLog:
    """
    Read the laser records of a CARMEN log (.log, .log.gz, or any gzip / text file).

    Lines that are not FLASER / ROBOTLASER1 are ignored; malformed laser lines, and lines longer
    than MAX_LINE_BYTES, are skipped and counted. The file is streamed: memory grows with the
    records kept, not with the (decompressed) file size. Raises ValueError when the file cannot
    be read (missing, truncated gzip, not UTF-8 text) or holds no usable laser record.
    """
    records, skipped, examples, front, robotlaser = [], 0, [], 0.0, None

    def skip(lineno, why):
        nonlocal skipped
        skipped += 1
        if len(examples) < 3:
            examples.append(f'line {lineno}: {why}')

    lineno = 0
    try:
        with open(path, 'rb') as plain:      # opened once: a pipe (/dev/stdin) is read once
            mode = os.fstat(plain.fileno()).st_mode
            if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) or stat.S_ISSOCK(mode):
                # /dev/zero streamed forever (convert never ended); a terminal waits for typing
                raise ValueError(f'{path}: a device, not a CARMEN log file (a file or a pipe)')
            gzipped = plain.peek(2)[:2] == b'\x1f\x8b'
            fh = gzip.GzipFile(fileobj=plain, mode='rb') if gzipped else plain
            for lineno, (raw, over_long) in enumerate(_lines(fh), 1):
                if over_long:
                    skip(lineno, f'longer than {MAX_LINE_BYTES:,} bytes')
                    continue
                tok = raw.decode('utf-8', errors='strict').split()
                if len(tok) >= 3 and tok[:2] == ['PARAM', 'robot_frontlaser_offset']:
                    try:
                        front = float(tok[2]) if np.isfinite(float(tok[2])) else 0.0
                    except ValueError:
                        pass
                    continue
                if not tok or tok[0] not in ('FLASER', 'ROBOTLASER1'):
                    continue
                try:
                    rec = _parse_flaser(tok) if tok[0] == 'FLASER' else _parse_robotlaser(tok)
                except IndexError:
                    skip(lineno, f'{tok[0]} record is shorter than its counts say')
                    continue
                except ValueError as exc:
                    text = str(exc)
                    if text.startswith(('invalid literal', 'could not convert')):
                        text = f'{tok[0]} record has a field that is not a number ({text})'
                    skip(lineno, text)
                    continue
                records.append(rec)
                if robotlaser is None and tok[0] == 'ROBOTLASER1':
                    robotlaser = rec
    except FileNotFoundError:
        raise ValueError(f'{path}: no such file') from None
    except IsADirectoryError:
        raise ValueError(f'{path}: is a folder, not a CARMEN log') from None
    except UnicodeDecodeError as exc:
        raise ValueError(f'{path}: unreadable log (not UTF-8 text at line {lineno}: '
                         f'{exc.reason})') from None
    except (OSError, EOFError, zlib.error) as exc:
        raise ValueError(f'{path}: unreadable or truncated log ({exc.__class__.__name__}: '
                         f'{exc})') from None
    if not records:
        raise ValueError(f'{path}: no usable FLASER or ROBOTLASER1 record'
                         + (f' ({skipped} malformed), e.g. {examples[0]}' if skipped else ''))
    no_return = np.inf
    flaser = [r.ranges for r in records if not np.isfinite(r.range_max)]
    if flaser:
        allr = np.concatenate(flaser)
        allr = allr[np.isfinite(allr) & (allr < MAX_RANGE)]
        values, counts = np.unique(allr, return_counts=True)
        repeated = values[counts > 1]
        # the largest repeated reading; a few single ones above it (at most 1 in 1000) are
        # glitches, which must not hide the code and turn every no-return into a point
        if repeated.size and (np.count_nonzero(allr > repeated[-1])
                              <= NO_RETURN_GLITCHES * allr.size):
            no_return = float(repeated[-1])
    bad = sum(int(np.count_nonzero(~(r.ranges >= 0))) for r in records)
    return CarmenLog(records, skipped, examples, no_return, _offset(robotlaser, front), bad)
