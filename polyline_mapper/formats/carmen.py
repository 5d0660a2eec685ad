"""
CARMEN log reader (FLASER and ROBOTLASER1 records), gzip or plain text.

Conventions (see the Radish logs' notes): FLASER carries ``n`` ranges, then the corrected laser
pose x, y, theta, the odometry pose, and time stamps; beam i is at -pi/2 + i*pi/n for even n and
-pi/2 + i*pi/(n-1) for odd n, relative to theta. ROBOTLASER1 states its start angle, angular
resolution and maximum range, and the laser pose after the remissions.

No-return readings: FLASER does not state the sensor's maximum range, and logs encode a missing
echo as that maximum (50, 51.2, 81.83, 81.91 m ...). When the largest reading of a log occurs more
than once, it is taken as that code and every reading >= 0.99 x it is dropped. ROBOTLASER1 records
use their own maximum range.
"""

from dataclasses import dataclass, field
import gzip
import zlib

import numpy as np

from ..scan import scan_to_points


@dataclass
class LaserRecord:
    """One scan: ranges (m), beam angles (rad, laser frame), laser pose (x, y, yaw), stamp (s)."""

    ranges: np.ndarray
    angles: np.ndarray
    pose: np.ndarray
    stamp: float
    range_max: float = np.inf


@dataclass
class CarmenLog:
    """The laser records of a log and the count of lines that could not be used."""

    records: list
    skipped: int = 0
    skipped_examples: list = field(default_factory=list)
    no_return: float = np.inf

    def points(self, range_max: float = None, progress=None) -> np.ndarray:
        """
        Register every scan with its (corrected) pose into one (N, 2) point set, metres.

        ``range_max`` additionally limits the usable range (m).
        """
        out = []
        recs = self.records if progress is None else progress(self.records)
        for rec in recs:
            top = min(rec.range_max, self.no_return * 0.99)
            if range_max is not None:
                top = min(top, range_max)
            out.append(scan_to_points(rec.ranges, rec.angles, rec.pose, 0.0, top))
        return np.concatenate(out) if out else np.zeros((0, 2))


def _flaser_angles(n: int) -> np.ndarray:
    return -np.pi / 2 + np.arange(n) * (np.pi / n if n % 2 == 0 else np.pi / max(n - 1, 1))


def _parse_flaser(tok: list) -> LaserRecord:
    n = int(tok[1])
    if n < 1 or len(tok) < n + 9:
        raise ValueError(f'FLASER announces {n} readings but the line has {len(tok)} fields')
    vals = np.array(tok[2:n + 9], dtype=np.float64)
    ranges, pose, stamp = vals[:n], vals[n:n + 3], vals[n + 6]
    if not np.isfinite(pose).all():
        raise ValueError('non-finite pose')
    return LaserRecord(ranges, _flaser_angles(n), pose, float(stamp))


def _parse_robotlaser(tok: list) -> LaserRecord:
    start, _, res, rmax = (float(v) for v in tok[2:6])
    n = int(tok[8])
    m = int(tok[9 + n])
    base = 10 + n + m
    if n < 1 or m < 0 or len(tok) < base + 12:
        raise ValueError('ROBOTLASER1 record is shorter than its counts say')
    ranges = np.array(tok[9:9 + n], dtype=np.float64)
    pose = np.array(tok[base:base + 3], dtype=np.float64)
    stamp = float(tok[base + 11])
    if not np.isfinite(pose).all():
        raise ValueError('non-finite pose')
    return LaserRecord(ranges, start + res * np.arange(n), pose, stamp, rmax)


def read_carmen(path: str) -> CarmenLog:
    """
    Read the laser records of a CARMEN log (.log, .log.gz, or any gzip / text file).

    Lines that are not FLASER / ROBOTLASER1 are ignored; malformed laser lines are skipped and
    counted. Raises ValueError when the file cannot be read (missing, truncated gzip, binary) or
    holds no usable laser record.
    """
    try:
        with open(path, 'rb') as fh:
            head = fh.read(2)
        opener = gzip.open if head == b'\x1f\x8b' else open
        with opener(path, 'rt', encoding='utf-8', errors='strict') as fh:
            lines = fh.readlines()
    except FileNotFoundError:
        raise ValueError(f'{path}: no such file') from None
    except (OSError, EOFError, zlib.error, UnicodeDecodeError) as exc:
        raise ValueError(f'{path}: unreadable or truncated log ({exc.__class__.__name__}: '
                         f'{exc})') from None
    records, skipped, examples = [], 0, []
    for lineno, line in enumerate(lines, 1):
        tok = line.split()
        if not tok or tok[0] not in ('FLASER', 'ROBOTLASER1'):
            continue
        try:
            rec = _parse_flaser(tok) if tok[0] == 'FLASER' else _parse_robotlaser(tok)
        except (ValueError, IndexError) as exc:
            skipped += 1
            if len(examples) < 3:
                examples.append(f'line {lineno}: {exc}')
            continue
        records.append(rec)
    if not records:
        raise ValueError(f'{path}: no usable FLASER or ROBOTLASER1 record'
                         + (f' ({skipped} malformed)' if skipped else ''))
    no_return = np.inf
    flaser = [r.ranges for r in records if not np.isfinite(r.range_max)]
    if flaser:
        allr = np.concatenate(flaser)
        allr = allr[np.isfinite(allr)]
        if allr.size:
            top = allr.max()
            if np.count_nonzero(allr == top) > 1:
                no_return = float(top)
    return CarmenLog(records, skipped, examples, no_return)
