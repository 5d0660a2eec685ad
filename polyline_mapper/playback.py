"""
Recordings as timed messages, for ``polyline-mapper play`` (ROS-free).

The publishing is in ``ros.player``. ``open_recording(INPUT)`` opens

- a bag (rosbag2 folder / .db3 / .mcap, ROS 1 .bag): its LaserScan topic (named, or the only
  one), its Odometry topic (named, or the only one, if any), /tf and /tf_static, each message at
  the bag's receive time;
- a CARMEN log: the messages ``polyline-mapper convert`` would write (``carmen_messages``);
- a built-in simulated drive, ``sim:office`` (the office floor with its curved wall),
  ``sim:hall`` or ``sim:corridors``: /scan in ``laser``, /tf map -> odom -> base_link,
  /tf_static base_link -> laser and /odom, ten scans a second, made at run time from a seed.

and yields a ``Recording`` whose ``messages()`` gives ``(log_time, topic, record)`` in time
order, ``record`` being a ``Scan``, an ``Odometry`` or a list of ``Transform`` (one TFMessage).
Only what the mapper uses is played: other topics of a bag, and the LaserScan fields the
records do not keep (intensities, scan and time increments) and Odometry's twist and
covariances, are not.
"""

from contextlib import contextmanager
from dataclasses import dataclass, field
import os
from typing import Callable, Iterator, Optional

import numpy as np

from .formats.records import Odometry, Scan, Transform
from .poses import quaternion_from_yaw

SIM_PREFIX = 'sim:'
SIM_WORLDS = ('office', 'hall', 'corridors')
SIM_START = 1000.0
"""Stamp of a simulated drive's first scan, seconds (non-zero: ROS reads time 0 as unset)."""
SIM_MOUNT = (0.2, 0.0, 0.0)
"""Laser pose on base_link in the simulated drives: 0.2 m ahead of the base's centre."""
SIM_MAP_TO_ODOM = (0.5, -0.3, 0.05)
"""map -> odom of the simulated drives (odometry frame offset from the map frame)."""


@dataclass
class Recording:
    """An opened recording: its timed messages, counts and a one-line description."""

    messages: Callable[[], Iterator[tuple]]
    """Call for an iterator of (log_time s, topic, record) in time order; callable again."""
    scan_count: int
    description: str
    warnings: list = field(default_factory=list)
    drive: Optional[object] = None
    """The SimulatedDrive of a ``sim:`` recording (its true poses and walls), else None."""


def is_sim(path: str) -> bool:
    """Return whether ``path`` names a built-in simulated drive (``sim:office``...)."""
    return str(path).startswith(SIM_PREFIX)


def make_drive(name: str, seed: int = 1, noise: float = 0.01, beams: int = 541):
    """Return the SimulatedDrive of ``sim:<name>``; ValueError for an unknown world."""
    from .sim import corridor_loop, hall_with_arc, LaserSpec, office_floor, simulate_drive
    worlds = {'office': office_floor, 'hall': hall_with_arc, 'corridors': corridor_loop}
    world = name[len(SIM_PREFIX):] if is_sim(name) else name
    if world not in worlds:
        raise ValueError(f'{name}: unknown simulated drive (expected one of '
                         f'{", ".join(SIM_PREFIX + w for w in SIM_WORLDS)})')
    if not (np.isfinite(noise) and noise >= 0):
        raise ValueError(f'noise must be a finite number >= 0 (m), got {noise!r}')
    return simulate_drive(worlds[world](), LaserSpec(beams=beams, noise=noise), rng=seed)


def _planar(stamp: float, parent: str, child: str, pose, static: bool = False) -> Transform:
    return Transform(float(stamp), parent, child, np.array([pose[0], pose[1], 0.0]),
                     quaternion_from_yaw(float(pose[2])), static)


def drive_messages(drive, start: float = SIM_START) -> Iterator[tuple]:
    """
    Yield ``(log_time, topic, record)`` for a SimulatedDrive, as a robot would record it.

    The drive's poses are laser poses in the map frame; base_link carries the laser at
    ``SIM_MOUNT`` and odom sits at ``SIM_MAP_TO_ODOM`` in map, so a mapper must chain
    map -> odom -> base_link -> laser to place the scans.
    """
    from .formats.convert import se2_compose, se2_inverse
    spec = drive.spec
    mount = np.asarray(SIM_MOUNT, dtype=float)
    base = se2_compose(drive.poses, se2_inverse(mount))
    odom = se2_compose(se2_inverse(np.asarray(SIM_MAP_TO_ODOM, dtype=float)), base)
    stamps = start + np.asarray(drive.stamps, dtype=float)
    yield stamps[0], '/tf_static', [_planar(stamps[0], 'base_link', 'laser', mount, True)]
    for i, t in enumerate(stamps.tolist()):
        tf_base = _planar(t, 'odom', 'base_link', odom[i])
        yield t, '/tf', [_planar(t, 'map', 'odom', SIM_MAP_TO_ODOM), tf_base]
        yield t, '/odom', Odometry(t, 'odom', 'base_link', tf_base.translation,
                                   tf_base.rotation)
        yield t, '/scan', Scan(t, 'laser', spec.angle_min, spec.angle_increment,
                               spec.range_min, spec.range_max,
                               np.asarray(drive.ranges[i], dtype=np.float32))


@contextmanager
def open_recording(path: str, scan_topic: str = None, odom_topic: str = None,
                   period: float = 1.0, seed: int = 1, noise: float = 0.01) -> Iterator[Recording]:
    """
    Open a bag, a CARMEN log or a ``sim:`` drive for playing (context manager).

    ``period``: seconds between a CARMEN log's scans when its times do not increase.
    ``seed``, ``noise``: of a ``sim:`` drive. Raises ValueError (BagError for bags) with one
    line when the input cannot be used.
    """
    from .formats.bag import BagReader, is_bag
    from .formats.convert import carmen_messages, is_carmen, read_for_messages
    if is_sim(path):
        if scan_topic is not None or odom_topic is not None:
            raise ValueError('--scan-topic and --odom-topic apply to bags, not simulated drives')
        drive = make_drive(path, seed, noise)
        yield Recording(lambda: drive_messages(drive), len(drive.poses),
                        f'simulated drive {path}, {len(drive.poses)} scans of '
                        f'{drive.spec.beams} beams', drive=drive)
        return
    if is_carmen(path):
        log, stamps, warnings = read_for_messages(path, period, scan_topic, odom_topic)

        def carmen():
            for topic, record, t in carmen_messages(log, stamps):
                yield t, topic, record
        yield Recording(carmen, len(log.records), f'CARMEN log, {len(log.records)} scans',
                        warnings)
        return
    if not os.path.exists(path):
        raise ValueError(f'{path}: no such file or folder')
    if not is_bag(path):
        raise ValueError(f'{path}: unknown input type (expected a rosbag2 folder, .db3, .mcap, '
                         '.bag, a CARMEN .log / .log.gz, or sim:office)')
    with BagReader(path, scan_topic, odom_topic, odometry='auto') as bag:
        topics = [bag.scan_topic] + ([bag.odom_topic] if bag.odom_topic else []) + bag.tf_topics
        count = bag.scan_count

    def bag_messages():
        # A fresh reader per pass (--loop); the topics were checked on opening above.
        with BagReader(path, scan_topic, odom_topic, odometry='auto') as again:
            yield from again.messages()
    yield Recording(bag_messages, count, f'bag, {count} scans; topics {", ".join(topics)}')
