"""
CARMEN log -> rosbag2, so real logs can be replayed through the bag path and the live node.

The messages are ``recordings.carmen_messages``, those ``replay`` and ``play`` read from the log
itself. Per laser record, at the record's stamp (``CarmenLog.stamps``: the log times when they
increase, else 1 s apart), the bag gets

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

import numpy as np

from .bag import BagWriter
from .carmen import read_carmen
from .output import check_new_folder
from ..recordings import carmen_messages, OdometryDrift


def carmen_to_bag(log_path: str, out_path: str, storage: str = 'sqlite3', period: float = 1.0,
                  progress=None, drift_seed: int = None,
                  drift_model: OdometryDrift = None) -> dict:
    """
    Convert a CARMEN log to a new rosbag2 folder ``out_path`` (sqlite3 or mcap storage).

    ``period`` (s) spaces the stamps when the log's times do not increase. ``progress`` wraps
    the message iterator (e.g. tqdm). The bag is written under a temporary name and renamed, so
    a failure leaves nothing behind. Returns a summary: scans, stamps_made_up, laser_offset,
    skipped (malformed log lines) and examples. Raises ValueError on a bad log, an existing
    output or a bad storage name or period.

    ``drift_seed``: write a robot without a localizer instead (``recordings.OdometryDrift``,
    seeded): /odom and /tf odom -> base_link drift like wheel odometry, no map frame.
    ``drift_model``: that drift's model (default ``OdometryDrift()``, issue 19's; all zero:
    odometry that follows the corrected poses exactly, still without a map frame).
    """
    if storage not in ('sqlite3', 'mcap'):
        raise ValueError(f'storage must be sqlite3 or mcap, got {storage!r}')
    if not (np.isfinite(period) and period > 0):
        raise ValueError(f'period must be a positive number of seconds, got {period!r}')
    check_new_folder(out_path, [log_path])
    log = read_carmen(log_path)
    stamps, made_up = log.stamps(period)
    parent = os.path.dirname(os.path.abspath(out_path))
    try:
        os.makedirs(parent, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix='.tmp-bag-', dir=parent)
    except OSError as exc:              # named as the user named it, not the temporary folder
        raise OSError(exc.errno, exc.strerror, os.fspath(out_path)) from None
    try:
        bag = os.path.join(tmp, os.path.basename(os.path.abspath(out_path)))
        drift = (None if drift_seed is None
                 else (drift_model or OdometryDrift(), int(drift_seed)))
        messages = carmen_messages(log, stamps, drift)
        with BagWriter(bag, storage) as out:
            for t, topic, record in (messages if progress is None else progress(messages)):
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
