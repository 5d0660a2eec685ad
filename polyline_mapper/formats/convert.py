"""
CARMEN log -> rosbag2, so real logs can be replayed through the bag path and the live node.

Per laser record, at the record's stamp (``CarmenLog.stamps``: the log times when they increase,
else 1 s apart), the bag gets

- ``/scan`` sensor_msgs/LaserScan in frame ``laser`` (float32 ranges; ``range_max`` is the log's
  no-return limit, so no-return readings are invalid by REP 117);
- ``/tf``: ``odom -> base_link`` from the record's odometry pose and ``map -> odom`` chosen so
  that ``map -> odom -> base_link -> laser`` is the corrected laser pose of the record;
- ``/odom`` nav_msgs/Odometry, ``base_link`` in ``odom`` (the same odometry pose, zero twist);

and once ``/tf_static`` ``base_link -> laser`` from the log's laser offset (zero if it has none).
The Radish logs' odometry fields repeat the corrected pose, so their ``map -> odom`` is nearly
constant and ``/odom`` is not raw wheel odometry.
"""

import os
import shutil
import tempfile
from typing import Iterator

import numpy as np

from .bag import BagWriter
from .carmen import CarmenLog, read_carmen
from .output import check_new_folder
from .records import Odometry, Transform
from ..poses import quaternion_from_yaw

CARMEN_SUFFIXES = ('.log', '.log.gz', '.clf', '.clf.gz', '.carmen', '.carmen.gz')


def se2_compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Compose planar poses row-wise: a then b, (..., 3) arrays of (x, y, yaw)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1],
                     a[..., 1] + s * b[..., 0] + c * b[..., 1], a[..., 2] + b[..., 2]], axis=-1)


def se2_inverse(a: np.ndarray) -> np.ndarray:
    """Invert planar poses row-wise, (..., 3) arrays of (x, y, yaw)."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1], -a[..., 2]],
                    axis=-1)


def _transform(stamp, parent, child, pose, static=False) -> Transform:
    return Transform(float(stamp), parent, child, np.array([pose[0], pose[1], 0.0]),
                     quaternion_from_yaw(float(pose[2])), static)


def carmen_messages(log: CarmenLog, stamps: np.ndarray) -> Iterator[tuple]:
    """
    Yield ``(topic, record, log_time)`` for a log, in the order a bag of it holds them.

    ``record`` is a list of Transform (/tf_static, /tf), an Odometry (/odom) or a Scan (/scan,
    without pose: it is found through /tf). ``stamps`` (R,) seconds, one per laser record.
    """
    mount = log.laser_offset
    laser = np.array([r.pose for r in log.records])
    odom = np.array([r.odom for r in log.records])
    map_odom = se2_compose(se2_compose(laser, se2_inverse(mount)), se2_inverse(odom))
    yield '/tf_static', [_transform(stamps[0], 'base_link', 'laser', mount, True)], stamps[0]
    for i, scan in enumerate(log.scans(stamps, frame_id='laser', with_pose=False)):
        t = float(stamps[i])
        base = _transform(t, 'odom', 'base_link', odom[i])
        yield '/tf', [_transform(t, 'map', 'odom', map_odom[i]), base], t
        yield '/odom', Odometry(t, 'odom', 'base_link', base.translation, base.rotation), t
        yield '/scan', scan, t


def is_carmen(path) -> bool:
    """Return whether ``path`` is an existing file with a CARMEN log suffix."""
    return str(path).lower().endswith(CARMEN_SUFFIXES) and os.path.isfile(path)


def read_for_messages(path: str, period: float = 1.0, scan_topic: str = None,
                      odom_topic: str = None) -> tuple:
    """
    Read a CARMEN log to replay or play it: return (log, stamps (R,), warnings).

    ``stamps`` as ``CarmenLog.stamps(period)``; ``warnings`` name skipped malformed records.
    ValueError when topic names are given (they apply to bags) or the log cannot be read.
    """
    if scan_topic is not None or odom_topic is not None:
        raise ValueError('--scan-topic and --odom-topic apply to bags, not CARMEN logs')
    log = read_carmen(path)
    stamps, _ = log.stamps(period)
    warnings = []
    if log.skipped:
        warnings.append(f'{path}: skipped {log.skipped} malformed laser record(s), e.g. '
                        f'{log.skipped_examples[0]}')
    return log, stamps, warnings


def carmen_to_bag(log_path: str, out_path: str, storage: str = 'sqlite3', period: float = 1.0,
                  progress=None) -> dict:
    """
    Convert a CARMEN log to a new rosbag2 folder ``out_path`` (sqlite3 or mcap storage).

    ``period`` (s) spaces the stamps when the log's times do not increase. ``progress`` wraps
    the message iterator (e.g. tqdm). The bag is written under a temporary name and renamed, so
    a failure leaves nothing behind. Returns a summary: scans, stamps_made_up, laser_offset,
    skipped (malformed log lines) and examples. Raises ValueError on a bad log, an existing
    output or a bad storage name or period.
    """
    if storage not in ('sqlite3', 'mcap'):
        raise ValueError(f'storage must be sqlite3 or mcap, got {storage!r}')
    if not (np.isfinite(period) and period > 0):
        raise ValueError(f'period must be a positive number of seconds, got {period!r}')
    check_new_folder(out_path, [log_path])
    log = read_carmen(log_path)
    stamps, made_up = log.stamps(period)
    parent = os.path.dirname(os.path.abspath(out_path))
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix='.tmp-bag-', dir=parent)
    try:
        bag = os.path.join(tmp, os.path.basename(os.path.abspath(out_path)))
        messages = carmen_messages(log, stamps)
        with BagWriter(bag, storage) as out:
            for topic, record, t in (messages if progress is None else progress(messages)):
                out.write(topic, record, t)
        _rename_folder(bag, out_path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {'scans': len(log.records), 'stamps_made_up': bool(made_up),
            'laser_offset': log.laser_offset.tolist(), 'skipped': log.skipped,
            'skipped_examples': list(log.skipped_examples)}


def _rename_folder(src: str, dst: str) -> None:
    """Move a finished folder to its name, refusing to replace anything there."""
    if os.path.lexists(dst):
        raise ValueError(f'{dst}: exists already (a bag is written to a new folder)')
    os.rename(src, dst)
