"""
Every input the tools read, opened in one place: point files, CARMEN logs, bags, simulated drives.

``kind_of(path)`` names an input's kind from one suffix table (``SUFFIXES``):

- ``points``: an (N, 2) point file, .npy / .csv / .txt / .xy (for ``fit`` and ``plot --points``);
- ``carmen``: a CARMEN log, .log / .clf / .carmen, gzipped or not;
- ``bag``: a rosbag2 folder (with metadata.yaml), a .db3 or .mcap storage file, a ROS 1 .bag;
- ``sim``: a built-in simulated drive, ``sim:office`` (the office floor with its curved wall),
  ``sim:hall``, ``sim:corridors`` or ``sim:office_dynamic`` (the office with people walking, a
  door that opens and a box carried away; ``sim:office-dynamic`` too), made at run time from a
  seed, with options after commas
  (``SIM_OPTIONS``), e.g. ``sim:office,odom_drift=3,moving_sensor=1``: wheel odometry that
  drifts (``OdometryDrift`` seeded 3; no map frame) and a lidar whose beams are taken over the
  scan time (``time_increment`` set).

``read_points`` reads the points of a point file or a CARMEN log (each scan at its corrected
pose). ``open_recording`` opens a log, a bag or a drive as a ``Recording``: timed messages
``(log_time, topic, record)``, ``record`` being a ``Scan``, an ``Odometry``, a list of
``Transform`` (one TFMessage) or, for a bag message that does not decode, a ``Skipped``
(``formats.records``); ``flat_records`` lists the records alone, a TFMessage's one by one.
Only what the mapper uses is kept: other topics of a bag, and the LaserScan fields the
records do not hold (intensities) and Odometry's twist and covariances, are not.

One message order for every kind, the one a robot records and ``polyline-mapper convert``
writes: /tf_static with the laser mount first, then per scan /tf (map -> odom, odom ->
base_link), /odom and /scan, all logged at the scan's stamp. A bag keeps its recording order.
CARMEN logs and simulated drives become messages through one builder, ``robot_messages``
(laser poses + mount -> transforms and odometry), which the tests use too.
"""

from contextlib import contextmanager
from dataclasses import dataclass, replace
import math
import os
from typing import Callable, Iterator, Optional

import numpy as np

from .core.register import ODOMETRY_NOISE
from .formats.bag import BAG_SUFFIXES
from .formats.records import f32, last_angle, Odometry, Scan, Transform
from .poses import mount_quaternion, planar_transform, se2_compose, se2_inverse

KINDS = ('points', 'carmen', 'bag', 'sim')
SUFFIXES = {
    'points': ('.npy', '.csv', '.txt', '.xy'),
    'carmen': ('.log', '.log.gz', '.clf', '.clf.gz', '.carmen', '.carmen.gz'),
    'bag': BAG_SUFFIXES,
}
"""File name endings (lower case) of each kind; a rosbag2 folder is known by its metadata.yaml."""
SIM_PREFIX = 'sim:'
SIM_WORLDS = ('office', 'hall', 'corridors', 'office_dynamic')
"""Built-in simulated worlds, ``sim:WORLD``; ``office_dynamic``: the office with people
walking, a door opening at 20 s and a box carried away at 15 s (``sim.office_dynamic``)."""
SIM_ALIASES = {'office-dynamic': 'office_dynamic'}
"""Other spellings of a world's name accepted in ``sim:WORLD``."""
SIM_OPTIONS = {
    'odom_drift': 'seed: /odom and odom -> base_link drift like wheel odometry (OdometryDrift), '
                  'no map frame',
    'moving_sensor': '1: beams taken over the scan time (time_increment set), 0: at once',
    'step': 'metres between scans (default 0.25)',
    'rate': 'scans per second (default 10)',
    'turn': 'turn in place at the waypoints, at most this many radians per scan',
    'beams': 'beams per scan (default 541 over 270 degrees)',
}
"""Options of a ``sim:`` drive, ``sim:WORLD,KEY=VALUE,...``; none given: today's drive."""
SIM_LOWEST = {'step': 0.01, 'turn': 0.01, 'rate': 0.01}
"""Smallest step (m) and turn (rad) per scan: the drive's scans grow as their inverse; smallest
rate (scans a second): the stamps grow as its inverse (1e-300 made them infinite, which no map
file holds)."""
SIM_HIGHEST = {'step': 10.0, 'rate': 1000.0}
"""Largest step (m) and rate (scans a second; beyond it stamps would crowd a clock's 1 ns)."""
SIM_START = 1000.0
"""Stamp of a simulated drive's first scan, seconds (non-zero: ROS reads time 0 as unset)."""
SIM_MOUNT = (0.2, 0.0, 0.0)
"""Laser pose on base_link in the simulated drives: 0.2 m ahead of the base's centre."""
SIM_MAP_TO_ODOM = (0.5, -0.3, 0.05)
"""map -> odom of the simulated drives (odometry frame offset from the map frame)."""
FRAMES = ('map', 'odom', 'base_link', 'laser')
"""Frames of ``robot_messages``: map, odometry, robot base, laser (REP 105 names)."""


def sim_names() -> str:
    """Return the built-in simulated drives as a user types them: 'sim:office, sim:hall, ...'."""
    return ', '.join(SIM_PREFIX + w for w in SIM_WORLDS)


def accepted_inputs() -> str:
    """Return the accepted input kinds as text, for error messages."""
    return ('point files (' + ', '.join(SUFFIXES['points']) + '), CARMEN logs ('
            + ', '.join(SUFFIXES['carmen']) + '), bags (a rosbag2 folder, '
            + ', '.join(s for s in SUFFIXES['bag'] if s != '.bag') + ', a ROS 1 .bag) or a '
            'simulated drive (' + sim_names() + ')')


def kind_of(path) -> str:
    """
    Return the kind of input ``path`` is: 'points', 'carmen', 'bag' or 'sim'.

    Raises ValueError with one line for a missing file, an unknown simulated drive, a folder
    that is not a rosbag2 bag, an unknown suffix (the message lists the accepted kinds) or a
    file that is not a regular file (a device or a pipe would block or never end).
    """
    name = os.fspath(path) if isinstance(path, os.PathLike) else str(path)
    if name.startswith(SIM_PREFIX):
        sim_options(name)
        return 'sim'
    if not os.path.exists(name):
        raise ValueError(f'{name}: no such file or folder')
    if os.path.isdir(name):
        if os.path.isfile(os.path.join(name, 'metadata.yaml')):
            return 'bag'
        inside = sorted(f for f in os.listdir(name) if f.lower().endswith(('.db3', '.mcap')))
        if inside:      # a recording stopped before rosbag2 wrote its metadata (SIGKILL)
            raise ValueError(f'{name}: a folder without metadata.yaml, not a rosbag2 bag; its '
                             f'storage file can be read alone: give '
                             f'{os.path.join(name, inside[0])}')
        raise ValueError(f'{name}: a folder without metadata.yaml, not a rosbag2 bag (accepted '
                         f'inputs: {accepted_inputs()})')
    low = name.lower()
    kind = next((k for k, endings in SUFFIXES.items() if low.endswith(endings)), None)
    if kind is None:
        raise ValueError(f'{name}: unknown input type (accepted inputs: {accepted_inputs()})')
    if not os.path.isfile(name):
        raise ValueError(f'{name}: not a regular file')
    return kind


# -- poses + mount -> messages -------------------------------------------------------------------
def robot_messages(stamps, laser_poses, scans, mount=(0.0, 0.0, 0.0), upside_down: bool = False,
                   odom_poses=None, map_to_odom=None, frames: tuple = FRAMES, tf: bool = True,
                   static: bool = True, odom: bool = True,
                   tf_until: Optional[float] = None) -> Iterator[tuple]:
    """
    Yield ``(log_time, topic, record)`` of a robot carrying a laser, as it would record them.

    In the recordings' order: /tf_static (the mount), then per scan /tf, /odom and /scan, each
    stamped and logged at the scan's stamp. The base pose is the laser pose composed with the
    inverse mount, so a mapper must chain map -> odom -> base -> laser to place the scans.

    Parameters
    ----------
    stamps : (P,) float array
        Seconds, one per scan.
    laser_poses : (P, 3) float array
        (x, y, yaw) of the laser in the map frame, metres and radians.
    scans : iterable of P Scan
        The scans in the laser frame ``frames[3]``, beams counter-clockwise seen from above.
    mount : (3,) float
        (x, y, yaw) of the laser on the base: /tf_static base -> laser.
    upside_down : bool
        The laser is rolled 180 degrees on its mount (``mount_quaternion``): it sweeps
        clockwise seen from above, so each scan lists the same beams in reverse order. Its beam
        fan must be symmetric about the laser's x axis.
    odom_poses : (P, 3) float array, optional
        Base poses by odometry, in the odometry frame; map -> odom is then chosen per scan so
        that the chain gives the laser pose (CARMEN logs). Not with ``map_to_odom``.
    map_to_odom : (3,) float, optional
        A constant map -> odom; odometry is then its inverse composed with the base pose. None
        (and no ``odom_poses``): no map frame, odometry is the base pose itself.
    frames : tuple of 4 str
        Frame names of the map, the odometry, the robot base and the laser.
    tf, static, odom : bool
        Whether to write /tf, /tf_static and /odom.
    tf_until : float, optional
        Write no /tf stamped after this (s): a transform stream that stops.

    """
    stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
    laser = np.asarray(laser_poses, dtype=np.float64)
    mount = np.asarray(mount, dtype=np.float64)
    if laser.shape != (len(stamps), 3) or mount.shape != (3,):
        raise ValueError(f'laser_poses must be ({len(stamps)}, 3) like the stamps and mount '
                         f'(3,), got {laser.shape} and {mount.shape}')
    map_frame, odom_frame, base_frame, laser_frame = frames
    base = se2_compose(laser, se2_inverse(mount))
    if odom_poses is not None:
        if map_to_odom is not None:
            raise ValueError('give odom_poses or map_to_odom, not both')
        odometry = np.asarray(odom_poses, dtype=np.float64)
        if odometry.shape != laser.shape:
            raise ValueError(f'odom_poses must be {laser.shape}, got {odometry.shape}')
        map_odom = se2_compose(base, se2_inverse(odometry))
    elif map_to_odom is not None:
        fixed = np.asarray(map_to_odom, dtype=np.float64)
        odometry = se2_compose(se2_inverse(fixed), base)
        map_odom = np.broadcast_to(fixed, base.shape)
    else:
        odometry, map_odom = base, None
    if static and len(stamps):
        rotation = mount_quaternion(mount[2], True) if upside_down else None
        yield float(stamps[0]), '/tf_static', [planar_transform(
            stamps[0], base_frame, laser_frame, mount, True, rotation)]
    for i, scan in enumerate(scans):
        if i >= len(stamps):
            raise ValueError(f'more scans than the {len(stamps)} stamps')
        if scan.frame_id != laser_frame:
            raise ValueError(f'scan {i} is in frame {scan.frame_id!r}, not {laser_frame!r}')
        t = float(stamps[i])
        moved = planar_transform(t, odom_frame, base_frame, odometry[i])
        if tf and (tf_until is None or t <= tf_until):
            yield t, '/tf', ([] if map_odom is None else [
                planar_transform(t, map_frame, odom_frame, map_odom[i])]) + [moved]
        if odom:
            yield t, '/odom', Odometry(t, odom_frame, base_frame, moved.translation.copy(),
                                       moved.rotation.copy())
        yield t, '/scan', _flipped(scan) if upside_down else scan


def _flipped(scan: Scan) -> Scan:
    """Return the scan of an upside-down laser: the same beams listed in reverse order."""
    last = scan.angle_min + scan.angle_increment * (len(scan.ranges) - 1)
    if not math.isclose(scan.angle_min + last, 0.0, abs_tol=1e-6):
        raise ValueError('an upside-down laser needs a beam fan symmetric about its x axis '
                         f'(angles {scan.angle_min:.6f} .. {last:.6f} rad)')
    return replace(scan, ranges=np.ascontiguousarray(scan.ranges[::-1]))


@dataclass(frozen=True)
class OdometryDrift:
    """
    Wheel-odometry-like drift: each step's motion with Gaussian noise (issue 19's model).

    Between consecutive poses the true motion (forward, sideways: d metres in all; turn) gets
    independent zero-mean Gaussian noise with standard deviations ``translation`` x d on each
    axis and ``rotation`` + ``rotation_per_m`` x d radians on the heading. The first pose is
    true; the error then accumulates as on a robot without a localizer.

    The model's step is one record of a Radish log (about a second and half a metre apart).
    Odometry sampled faster (the simulator: a scan every 0.1 s) gets the same heading random
    walk per second when ``apply`` is given the poses' stamps: the constant heading term of a
    step of dt seconds is then ``rotation`` x sqrt(dt / ``period``) (0.0063 rad at 10 Hz), not
    0.02 rad a step, which at 10 Hz would turn a standing robot by 0.06 rad a second and
    bend every moving-sensor scan.
    """

    translation: float = ODOMETRY_NOISE.translation
    """Std of each axis's error, as a share of the step's length (0.05)."""
    rotation: float = ODOMETRY_NOISE.rotation
    """Std of the heading error of every step, radians (0.02)."""
    rotation_per_m: float = ODOMETRY_NOISE.rotation_per_m
    """Std of the heading error per metre travelled, radians (1 deg)."""
    period: float = ODOMETRY_NOISE.period
    """Seconds of the model's step (for ``apply`` with stamps; 1)."""

    def apply(self, poses, rng, stamps=None) -> np.ndarray:
        """
        Return drifted copies of ``poses`` ((P, 3) x, y, yaw), seeded by ``rng``.

        >>> p = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
        >>> d = OdometryDrift().apply(p, 0)
        >>> bool(np.array_equal(d[0], p[0])), bool(np.abs(d[1:, :2] - p[1:, :2]).max() < 1.0)
        (True, True)
        """
        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != 3 or not np.isfinite(poses).all():
            raise ValueError(f'poses must be (P, 3) finite (x, y, yaw), got {poses.shape}')
        if len(poses) < 2:
            return poses.copy()
        rng = np.random.default_rng(rng)
        steps = se2_compose(se2_inverse(poses[:-1]), poses[1:])        # motion in the robot frame
        dist = np.hypot(steps[:, 0], steps[:, 1])
        turn = self.rotation
        if stamps is not None:
            dt = np.diff(np.asarray(stamps, dtype=np.float64))
            if dt.shape != dist.shape or not (np.isfinite(dt).all() and (dt >= 0).all()):
                raise ValueError('stamps must be one finite, non-decreasing time per pose')
            turn = self.rotation * np.sqrt(dt / self.period)
        noisy = steps + rng.normal(size=steps.shape) * np.stack(
            [self.translation * dist, self.translation * dist,
             turn + self.rotation_per_m * dist], axis=1)
        # Chain the noisy steps: headings add up, each step turns with the heading before it.
        yaw = poses[0, 2] + np.concatenate([[0.0], np.cumsum(noisy[:, 2])])
        c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
        moves = np.stack([c * noisy[:, 0] - s * noisy[:, 1], s * noisy[:, 0] + c * noisy[:, 1]],
                         axis=1)
        xy = poses[0, :2] + np.concatenate([np.zeros((1, 2)), np.cumsum(moves, axis=0)])
        return np.column_stack([xy, yaw])


def carmen_messages(log, stamps, drift: Optional[tuple] = None) -> Iterator[tuple]:
    """
    Yield ``(log_time, topic, record)`` for a CARMEN log, as ``convert`` writes its bag.

    Per laser record at ``stamps`` (R,) seconds: /tf map -> odom -> base_link (odom -> base_link
    the record's odometry pose, map -> odom chosen so that the chain gives its corrected laser
    pose), /odom and the /scan in frame ``laser`` (LaserScan precision, no pose); once, first,
    /tf_static base_link -> laser from the log's laser offset. ``log``: a formats.carmen.CarmenLog.

    ``drift``: (OdometryDrift, seed) to write instead a robot without a localizer: /odom and
    /tf odom -> base_link follow the corrected base poses with that drift added, and there is no
    map frame (the first pose is true, so the odometry frame starts on the map frame).
    """
    laser = np.array([r.pose for r in log.records])
    scans = log.scans(stamps, frame_id='laser', with_pose=False)
    if drift is not None:
        model, seed = drift
        mount = np.asarray(log.laser_offset, dtype=np.float64)
        base = model.apply(se2_compose(laser, se2_inverse(mount)), seed)
        return robot_messages(stamps, se2_compose(base, mount), scans, mount=mount)
    odometry = np.array([r.odom for r in log.records])
    return robot_messages(stamps, laser, scans, mount=log.laser_offset, odom_poses=odometry)


def sim_options(name: str) -> tuple:
    """
    Parse ``sim:WORLD[,KEY=VALUE,...]``: return (world, options dict) (``SIM_OPTIONS``).

    Raises ValueError with one line for an unknown world, an unknown key or a bad value.

    >>> sim_options('sim:office,odom_drift=3,moving_sensor=1,turn=0.2')
    ('office', {'odom_drift': 3, 'moving_sensor': True, 'turn': 0.2})
    """
    text = str(name)
    world, *items = (text[len(SIM_PREFIX):] if text.startswith(SIM_PREFIX) else text).split(',')
    world = SIM_ALIASES.get(world, world)
    if world not in SIM_WORLDS:
        raise ValueError(f'{text}: unknown simulated drive (expected one of {sim_names()}, '
                         'options after commas)')
    out = {}
    for item in items:
        key, eq, value = (v.strip() for v in item.partition('='))
        if key not in SIM_OPTIONS or not eq:
            raise ValueError(f'{text}: unknown simulated drive option {item!r} (expected '
                             f'KEY=VALUE, KEY one of {", ".join(SIM_OPTIONS)})')
        try:
            if key in ('odom_drift', 'beams'):
                v = int(value)
                ok = 0 <= v < 2 ** 32 if key == 'odom_drift' else 2 <= v <= 100000
            elif key == 'moving_sensor':
                v = {'0': False, '1': True}[value]
                ok = True
            else:
                v = float(value)
                low = SIM_LOWEST.get(key, 0.0)      # a drive of 1e-9 m steps: 15 GB
                ok = (math.isfinite(v) and v > 0 and v >= low
                      and v <= SIM_HIGHEST.get(key, math.inf))
        except (KeyError, ValueError):
            ok = False
        if not ok:
            want = {'odom_drift': 'an integer seed >= 0', 'beams': 'an integer >= 2',
                    'moving_sensor': '0 or 1', 'step': 'a number of metres in [0.01, 10]',
                    'turn': 'a number of radians >= 0.01',
                    'rate': 'a number of scans per second in [0.01, 1000]'}
            raise ValueError(f'{text}: {key} must be {want.get(key, "a number > 0")}, got '
                             f'{value!r}')
        out[key] = v
    return world, out


def make_drive(name: str, seed: int = 1, noise: float = 0.01, beams: int = 541):
    """
    Return the SimulatedDrive of ``sim:<name>`` (or ``<name>``); ValueError if unknown.

    ``name`` may carry options (``sim_options``); its ``beams`` replaces the argument. The
    odometry drift is not part of the drive (``drive_messages`` adds it).
    """
    from .sim import (corridor_loop, hall_with_arc, LaserSpec, office_dynamic, office_floor,
                      simulate_drive)
    worlds = {'office': office_floor, 'hall': hall_with_arc, 'corridors': corridor_loop,
              'office_dynamic': office_dynamic}
    world, opts = sim_options(name)
    if not (np.isfinite(noise) and noise >= 0):
        raise ValueError(f'noise must be a finite number >= 0 (m), got {noise!r}')
    rate = opts.get('rate', 10.0)
    kw = {k: opts[k] for k in ('step', 'turn') if k in opts}
    return simulate_drive(worlds[world](), LaserSpec(beams=opts.get('beams', beams), noise=noise),
                          rng=seed, rate=rate,
                          scan_time=1.0 / rate if opts.get('moving_sensor') else 0.0, **kw)


def flat_records(messages) -> list:
    """Return the records of ``(log_time, topic, record)`` messages, a TFMessage's one by one."""
    out = []
    for _, _, record in messages:
        out.extend(record if isinstance(record, list) else [record])
    return out


def drive_messages(drive, start: float = SIM_START, mount=SIM_MOUNT, upside_down: bool = False,
                   map_to_odom=SIM_MAP_TO_ODOM, odom_drift: Optional[int] = None,
                   odometry: Optional[np.ndarray] = None, **options) -> Iterator[tuple]:
    """
    Yield ``(log_time, topic, record)`` for a SimulatedDrive, as a robot would record it.

    The drive's poses are laser poses in the map frame and its stamps start at 0: the messages
    are stamped ``start`` + those. The laser sits at ``mount`` on base_link (rolled when
    ``upside_down``), odom at ``map_to_odom`` in map. ``odom_drift`` (a seed): instead, a robot
    without a localizer, as ``carmen_messages`` writes one: /odom and /tf odom -> base_link
    follow the true base poses with ``OdometryDrift`` added (its heading random walk per
    second, at the drive's rate), and there is no map frame (the first pose is true).
    ``odometry`` ((P, 3) base poses, not with ``odom_drift``): the same with these poses as the
    odometry (a slip, ``benchmarks/slips.py``). A moving sensor's scans carry the drive's
    ``time_increment`` and ``scan_time``. ``options`` go to ``robot_messages``.
    """
    spec = drive.spec
    stamps = start + np.asarray(drive.stamps, dtype=np.float64)
    laser_frame = options.get('frames', FRAMES)[3]
    # The LaserScan fields at float32, as a bag or the node holds them, so that a drive
    # replayed directly maps as the same drive played or recorded.
    extra = ({'time_increment': f32(drive.time_increment), 'scan_time': f32(drive.scan_time)}
             if drive.time_increment > 0 else {})
    scans = (Scan(t, laser_frame, f32(spec.angle_min), f32(spec.angle_increment),
                  f32(spec.range_min), f32(spec.range_max), np.asarray(ranges, dtype=np.float32),
                  angle_max=last_angle(spec.angle_min, spec.angle_increment, len(ranges)),
                  **extra)
             for t, ranges in zip(stamps.tolist(), drive.ranges))
    laser = drive.poses
    if odom_drift is not None and odometry is not None:
        raise ValueError('give odom_drift or odometry, not both')
    if odom_drift is not None or odometry is not None:
        m = np.asarray(mount, dtype=np.float64)
        base = (np.asarray(odometry, dtype=np.float64) if odometry is not None else
                OdometryDrift().apply(se2_compose(laser, se2_inverse(m)), odom_drift,
                                      stamps=stamps))
        laser, map_to_odom = se2_compose(base, m), None
    return robot_messages(stamps, laser, scans, mount=mount, upside_down=upside_down,
                          map_to_odom=map_to_odom, **options)


def thin_odometry(records: list, every: int) -> list:
    """
    Return ``records`` with one odometry message in ``every`` kept, as a slower base sends it.

    The odometry: the Odometry records and the dynamic transforms (odom -> base_link), each
    kind counted on its own, its first kept; every other record as it is
    (``benchmarks/odom_rate.py``).
    """
    seen = {Odometry: 0, Transform: 0}
    out = []
    for r in records:
        if isinstance(r, Odometry) or (isinstance(r, Transform) and not r.static):
            seen[type(r)] += 1
            if (seen[type(r)] - 1) % every:
                continue
        out.append(r)
    return out


# -- opening -------------------------------------------------------------------------------------
class Recording:
    """
    An opened log, bag or simulated drive: its timed messages, counts and a description.

    ``messages()`` (callable again, each call a new pass) yields ``(log_time s, topic, record)``
    in time order; ``records()`` the same stream one record at a time (Scan, Transform,
    Odometry, PoseEstimate, Skipped). ``drive`` is the SimulatedDrive of a ``sim:`` input (its
    true poses and walls), else None. ``warnings``: lines to show the user (e.g. skipped
    malformed lines). ``estimate_topic``: the topic of the pose estimates a bag holds, or None.
    ``odometry``: whether it holds odometry (a bag with an Odometry topic; logs and drives do).
    ``scan_topic``, ``odom_topic``: a bag's LaserScan topic and the Odometry topic read (None
    when none is read), as chosen or found; None for logs and drives.
    """

    def __init__(self, messages: Callable[[], Iterator[tuple]], scan_count: int,
                 description: str, kind: str, warnings: list = None, drive=None,
                 estimate_topic: str = None, odometry: bool = True, scan_topic: str = None,
                 odom_topic: str = None):
        self._messages = messages
        self.scan_count = int(scan_count)
        self.description = description
        self.kind = kind
        self.warnings = list(warnings or [])
        self.drive = drive
        self.estimate_topic = estimate_topic
        self.odometry = bool(odometry)
        self.scan_topic = scan_topic
        self.odom_topic = odom_topic

    def messages(self) -> Iterator[tuple]:
        """Yield ``(log_time, topic, record)`` from the start of the recording."""
        return self._messages()

    def records(self) -> Iterator:
        """Yield the messages' records one by one (a TFMessage's transforms in order)."""
        for _, _, record in self._messages():
            if isinstance(record, list):
                yield from record
            else:
                yield record


@contextmanager
def open_recording(path, scan_topic: str = None, odom_topic: str = None, period: float = 1.0,
                   seed: int = 1, noise: float = 0.01, odometry='auto',
                   pose_source: str = None) -> Iterator[Recording]:
    """
    Open a CARMEN log, a bag or a ``sim:`` drive (context manager yielding a Recording).

    ``scan_topic``, ``odom_topic``: a bag's LaserScan and Odometry topics (default: the only
    one). ``odometry`` (bags): 'auto' or None reads the Odometry topic when ``odom_topic`` is
    given or the bag has exactly one, True requires one, False reads none (so a bag with two
    Odometry topics opens for a caller that does not need odometry). ``period``: seconds
    between a CARMEN log's scans when its times do not increase. ``seed``, ``noise`` (m): of a
    ``sim:`` drive. Raises ValueError (BagError for bags) with one line when the input cannot
    be used. ``pose_source``: how the caller places the scans; a bag without /tf is not warned
    about when that is 'scan' (by themselves), nor when it is 'odom' and the bag has odometry.
    """
    kind = kind_of(path)
    path = str(path)
    if kind == 'points':
        raise ValueError(f'{path}: a point file holds no scans (it is for fit and plot --points); '
                         'expected a CARMEN log, a bag or a simulated drive')
    if kind != 'bag' and (scan_topic is not None or odom_topic is not None):
        raise ValueError('--scan-topic and --odom-topic apply to bags, not '
                         + ('simulated drives' if kind == 'sim' else 'CARMEN logs'))
    if odometry not in (None, 'auto', True, False):
        raise ValueError(f"odometry must be None, 'auto', True or False, got {odometry!r}")
    if kind == 'sim':
        drive = make_drive(path, seed, noise)
        drift = sim_options(path)[1].get('odom_drift')
        how = ('' if drift is None else f', odometry drifting (seed {drift}), no map frame') + (
            ', moving sensor' if drive.time_increment > 0 else '')
        yield Recording(lambda: drive_messages(drive, odom_drift=drift), len(drive.poses),
                        f'simulated drive {path}, {len(drive.poses)} scans of '
                        f'{drive.spec.beams} beams{how}', kind, drive=drive)
    elif kind == 'carmen':
        log, stamps, warnings = read_log(path, period)
        desc = f'CARMEN log, {len(log.records)} scans'
        if log.skipped:
            desc += f', {log.skipped} malformed record(s) skipped'
        yield Recording(lambda: carmen_messages(log, stamps), len(log.records), desc, kind,
                        warnings)
    else:
        yield from _open_bag(path, scan_topic, odom_topic, 'auto' if odometry is None
                             else odometry, pose_source)


def _open_bag(path: str, scan_topic, odom_topic, odometry,
              pose_source: str = None) -> Iterator[Recording]:
    from .formats.bag import BagReader, ODOM_TYPE
    with BagReader(path, scan_topic, odom_topic, odometry=odometry) as bag:
        first = [bag]
        topics = [bag.scan_topic] + ([bag.odom_topic] if bag.odom_topic else []) + bag.tf_topics \
            + ([bag.estimate_topic] if bag.estimate_topic else [])
        warnings = list(bag.warnings)       # e.g. a ROS 1 index rebuilt from the chunks
        odometry_topic = ODOM_TYPE in bag.topics.values()
        if not bag.tf_topics and pose_source != 'scan':
            if odometry_topic and pose_source != 'odom':
                warnings.append(f'{path}: no /tf or /tf_static topic: its scans can be placed '
                                'by odometry (--pose-source odom) or by the scans alone '
                                '(--pose-source scan)')
            elif not odometry_topic:
                warnings.append(f'{path}: no /tf, /tf_static or Odometry topic: its scans can '
                                'be placed by the scans alone (--pose-source scan)')

        def messages():
            if first:                       # the first pass reads the reader opened here
                yield from first.pop().messages()
                return
            with BagReader(path, scan_topic, odom_topic, odometry=odometry) as again:
                yield from again.messages()
        yield Recording(messages, bag.scan_count, f'bag, {bag.scan_count} scans on '
                        f'{bag.scan_topic}; topics {", ".join(topics)}', 'bag', warnings,
                        estimate_topic=bag.estimate_topic, odometry=odometry_topic,
                        scan_topic=bag.scan_topic, odom_topic=bag.odom_topic)


def read_log(path: str, period: float = 1.0) -> tuple:
    """
    Read a CARMEN log to replay or play it: return (log, stamps (R,) s, warnings).

    ``stamps`` as ``CarmenLog.stamps(period)``; ``warnings`` name skipped malformed records and
    made-up stamps. ValueError when the log cannot be read or ``period`` is not > 0.
    """
    from .formats.carmen import read_carmen
    if not _positive(period) or math.isinf(period):
        raise ValueError(f'period must be a positive number of seconds, got {period!r}')
    log = read_carmen(path)
    stamps, made_up = log.stamps(period)
    warnings = log_warnings(path, log)
    if made_up:
        warnings.append(f'{path}: log times do not increase; made-up stamps {period:g} s '
                        'apart, from t = 1 s')
    return log, stamps, warnings


def log_warnings(path: str, log) -> list:
    """Return the lines to warn of a CarmenLog: malformed records, readings that are no range."""
    out = []
    if log.skipped:
        out.append(f'{path}: skipped {log.skipped} malformed laser record(s), e.g. '
                   f'{log.skipped_examples[0]}')
    if log.bad_readings:
        out.append(f'{path}: dropped {log.bad_readings} reading(s) that are no range (negative '
                   'or NaN)')
    return out


def read_points(path, range_max: float = None, progress=None,
                warn: Callable[[str], None] = None) -> tuple:
    """
    Read the points of a point file or a CARMEN log: return ((N, 2) float array m, description).

    A log's scans are placed at their corrected poses (``CarmenLog.points``); ``range_max`` (m,
    logs only) limits the usable range further, ``progress`` wraps the scan iterator (e.g.
    tqdm), ``warn`` gets each warning line (skipped malformed log lines). A bag or a simulated
    drive has no points to read: its scans need poses, so it is registered by the mapping
    session (``replay`` without mapping); for those, as for anything unreadable, ValueError
    with one line.
    """
    kind = kind_of(path)
    path = str(path)
    if kind in ('bag', 'sim'):
        raise ValueError(f'{path}: a {"bag" if kind == "bag" else "simulated drive"} holds '
                         'scans, not points: its points come from replaying it')
    if range_max is not None:
        if kind == 'points':
            raise ValueError('--range-max applies to laser logs only')
        if not _positive(range_max):
            raise ValueError(f'range_max must be a number > 0 (m), got {range_max!r}')
    if kind == 'points':
        from .formats.points import read_points as read_file
        return read_file(path), 'point file'
    points, _, desc = _read_log(path, range_max, progress, warn)
    return points, desc


def read_beams(path, range_max: float = None, progress=None,
               warn: Callable[[str], None] = None) -> tuple:
    """
    Read a point file or a CARMEN log with the laser position of every point.

    Returns ``(points, origins, description)``: ``points`` as ``read_points`` gives them (the
    same array for a log), ``origins`` (N, 2) the laser position (corrected pose) of the record
    each point comes from, metres, or None for a point file (bare points have no beams). Bags
    and simulated drives: ValueError as in ``read_points``.
    """
    if kind_of(path) != 'carmen':
        points, desc = read_points(path, range_max, progress, warn)
        return points, None, desc
    if range_max is not None and not _positive(range_max):
        raise ValueError(f'range_max must be a number > 0 (m), got {range_max!r}')
    return _read_log(str(path), range_max, progress, warn)


def _read_log(path: str, range_max, progress, warn) -> tuple:
    """Read a CARMEN log's points and their laser positions; warn of malformed records."""
    from .formats.carmen import read_carmen
    from .formats.points import check_coordinates
    log = read_carmen(path)
    desc = f'CARMEN log, {len(log.records)} scans'
    if log.skipped:
        desc += f', {log.skipped} malformed record(s) skipped'
    for line in log_warnings(path, log) if warn is not None else ():
        warn(line)
    points, origins = log.beams(range_max, progress)
    return check_coordinates(points, path), origins, desc


def drive_beams(drive) -> tuple:
    """
    Return the points of a simulated drive and their laser positions, two (N, 2) arrays.

    ``points`` equal ``drive.points()`` (true poses); ``origins`` are the scan poses, or each
    beam's with a moving sensor (``SimulatedDrive.origins``).
    """
    return drive.points(), drive.origins()


def _positive(value) -> bool:
    """Return whether ``value`` is a real number > 0 (inf included, NaN and bools not)."""
    try:
        return not isinstance(value, (bool, str)) and float(value) > 0
    except (TypeError, ValueError):
        return False
