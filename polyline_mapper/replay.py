"""
Offline replay: scans from a bag or a CARMEN log -> laser poses -> the incremental mapper.

The same steps as the live node, without ROS:

- poses come from ``poses.TransformBuffer2D``. ``pose_source='tf'``: the pose of the scan's
  frame in the fixed frame at the scan's header stamp, from /tf and /tf_static. ``'odom'``: the
  odometry pose (``nav_msgs/Odometry``, the child frame in the odometry frame, interpolated at
  the scan stamp) composed with the laser mount: ``mount`` when given (like the node's
  ``laser_*`` parameters), else the scan frame's transform from /tf_static; the map is then in
  the odometry frame. A laser mounted upside down
  has its beam angles mirrored (``PlanarPose.beam_angles``).
- a scan waits, like a tf2 message filter, until pose data stamped at or after it has arrived
  (or ``wait`` seconds of newer pose data, or the end of the input); a scan whose pose cannot be
  given then is skipped and counted under ``no pose: <cause>`` (``too_new``, ``too_old``,
  ``unknown_frame``, ``not_connected``, ``no_tf``, ``tilted``). Before that, every scan passes
  the node's ``check_scan`` (ROS-free); one that fails is counted as ``bad scan: <cause>``
  (``no_valid_ranges``, ``range_limits``, ``angle_increment``, ``empty_scan``).
- ``scan_to_points`` (REP 117 filtering) and ``IncrementalMapper.update`` do the rest; the time
  of both together is the update time.

CARMEN logs are replayed as the messages the bag made of them by ``polyline-mapper convert``
holds (``formats.convert.carmen_messages``): the corrected laser pose of each record reaches the
mapper through the same TF lookups, and scans are used in LaserScan precision (float32 ranges and
angles, see ``formats.records``). A log and its bag therefore give the same map.
"""

from collections import Counter, deque
from contextlib import contextmanager
from dataclasses import dataclass, field
import math
import os
import time
from typing import Iterable, Iterator, Optional

import numpy as np

from .core import map_metrics
from .core.incremental import IncrementalConfig, IncrementalMapper
from .formats.records import Odometry, Scan, Skipped, Transform
from .poses import PlanarPose, quaternion_from_yaw, TransformBuffer2D, TransformLookupError
from .scan import check_scan, scan_to_points, ScanError

POSE_SOURCES = ('tf', 'odom')
MOUNT_FRAME = '_replay_laser'
"""Odom mode with an explicit mount: the laser frame hung under the odometry child frame."""


@dataclass
class ReplayOptions:
    """How scans get their poses (see the module docstring)."""

    pose_source: str = 'tf'
    fixed_frame: Optional[str] = None
    """Map frame for ``tf``; default: 'map' when the scan frame's tree has it, else its root."""
    every: int = 1
    """Use every N-th scan."""
    tolerance: float = 0.1
    """Seconds a stamp may lie outside the stored transforms and still use the nearest."""
    wait: float = 0.5
    """Seconds of newer pose data after which a scan without pose is given up."""
    mount: Optional[tuple] = None
    """(x, y, yaw) metres / radians of the laser in the odometry child frame (odom mode). When
    given it is used whatever the scan's frame and /tf_static say (as the node's laser_x,
    laser_y, laser_yaw, laser_upside_down parameters); when not, the scan frame's mount comes
    from /tf_static."""
    mount_upside_down: bool = False
    """The ``mount`` laser is rolled 180 degrees (its beams sweep clockwise seen from above)."""
    cache_seconds: float = 30.0

    def __post_init__(self):
        """Reject values that cannot work, naming the field."""
        if self.pose_source not in POSE_SOURCES:
            raise ValueError(f'pose_source must be tf or odom, got {self.pose_source!r}')
        if int(self.every) != self.every or self.every < 1:
            raise ValueError(f'every must be an integer >= 1, got {self.every!r}')
        for name in ('tolerance', 'wait'):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f'{name} must be a finite number >= 0, got {v!r}')
        if self.mount is not None:
            m = np.asarray(self.mount, dtype=float)
            if m.shape != (3,) or not np.isfinite(m).all():
                raise ValueError(f'mount must be 3 finite numbers (x, y, yaw), got {self.mount}')


class ReplayError(ValueError):
    """A problem that makes the whole replay meaningless (not one skipped record)."""


def mount_quaternion(yaw: float, upside_down: bool = False) -> np.ndarray:
    """Return the quaternion (x, y, z, w) of a mount: yaw about z, then rolled 180 deg if so."""
    if not upside_down:
        return quaternion_from_yaw(yaw)
    return np.array([math.cos(0.5 * yaw), math.sin(0.5 * yaw), 0.0, 0.0])


class PoseResolver:
    """Keep the transforms (and odometry) seen so far; give the laser pose of a scan."""

    def __init__(self, options: ReplayOptions):
        self.options = options
        self.buffer = TransformBuffer2D(options.cache_seconds)
        self.fixed_frame = options.fixed_frame
        self.latest = -math.inf
        """Newest stamp of dynamic pose data (transforms or odometry), seconds."""
        self._parents = {}
        self._mounted = False

    def add(self, record) -> None:
        """Take a Transform or an Odometry record (others are ignored); ValueError if bad."""
        odom_mode = self.options.pose_source == 'odom'
        if isinstance(record, Transform):
            if odom_mode and not record.static:
                return          # odom mode: the odometry topic is the only moving edge
            self.buffer.set_transform(record.parent, record.child, record.stamp,
                                      record.translation, record.rotation, record.static)
            self._parents[record.child] = record.parent
            if not record.static:
                self.latest = max(self.latest, record.stamp)
        elif isinstance(record, Odometry) and odom_mode:
            if self.fixed_frame is None:
                self.fixed_frame = record.frame_id
            elif record.frame_id != self.fixed_frame:
                raise ReplayError(f'odometry in frame {record.frame_id!r}, expected '
                                  f'{self.fixed_frame!r} (with --pose-source odom the map is '
                                  'in the odometry frame)')
            self.buffer.set_transform(record.frame_id, record.child_frame_id, record.stamp,
                                      record.translation, record.rotation)
            self._parents[record.child_frame_id] = record.frame_id
            self.latest = max(self.latest, record.stamp)
            m = self.options.mount
            if m is not None and not self._mounted:
                self.buffer.set_transform(record.child_frame_id, MOUNT_FRAME, 0.0,
                                          (m[0], m[1], 0.0),
                                          mount_quaternion(m[2], self.options.mount_upside_down),
                                          static=True)
                self._mounted = True

    def pose(self, scan: Scan) -> PlanarPose:
        """Return the laser pose of ``scan``; TransformLookupError (with ``cause``) if none."""
        if scan.pose is not None:
            x, y, yaw = (float(v) for v in scan.pose)
            return PlanarPose(x, y, yaw, False)
        frame = scan.frame_id
        if not frame:
            raise TransformLookupError('unknown_frame', 'the scan has an empty frame_id')
        if self.options.pose_source == 'odom':
            if self.fixed_frame is None:
                raise TransformLookupError('no_tf', 'no odometry received yet')
            target = self.fixed_frame
            if self.options.mount is not None:
                frame = MOUNT_FRAME
        else:
            target = self.fixed_frame or self._default_fixed(frame)
        pose = self.buffer.lookup_planar(target, frame, scan.stamp, self.options.tolerance)
        self.fixed_frame = target
        return pose

    def _default_fixed(self, frame: str) -> str:
        chain, seen = [frame], {frame}
        while chain[-1] in self._parents and self._parents[chain[-1]] not in seen:
            chain.append(self._parents[chain[-1]])
            seen.add(chain[-1])
        if len(chain) == 1:
            raise TransformLookupError(
                'unknown_frame' if self._parents else 'no_tf',
                f'frame {frame!r} has no transform to any other frame yet')
        return 'map' if 'map' in seen else chain[-1]


@dataclass
class ReplayResult:
    """What a replay produced: the mapper, the points it was fed, counts and times."""

    mapper: IncrementalMapper
    points: np.ndarray
    """(N, 2) every point given to the mapper, fixed frame, metres."""
    scans: int
    """Scans read (before --every)."""
    used: int
    """Scans given to the mapper."""
    skipped: Counter
    """Scans (or messages) not used, by cause."""
    examples: dict
    """One example message per skip cause."""
    update_ms: np.ndarray
    """Time of each map update (point conversion included), milliseconds."""
    fixed_frame: Optional[str]
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    def stats(self) -> dict:
        """Map quality over the replayed points, counts and update times, for the map JSON."""
        geo = self.mapper.polylines()
        stats = map_metrics(self.points, geo.segments)
        ms = self.update_ms
        stats.update(
            polylines=len(geo.polylines), scans=int(self.scans), scans_used=int(self.used),
            skipped=dict(sorted(self.skipped.items())),
            update_ms_median=round(float(np.median(ms)), 3) if ms.size else None,
            update_ms_p99=round(float(np.percentile(ms, 99)), 3) if ms.size else None,
            updates=int(ms.size), sigma=self.mapper.sigma, seconds=round(self.seconds, 3),
            fixed_frame=self.fixed_frame)
        stats.update(self.extra)
        return stats

    def skips(self) -> str:
        """Return the skipped counts as text, e.g. '3 no pose: too_new, 1 bad scan'."""
        return ', '.join(f'{n} {cause}' for cause, n in sorted(self.skipped.items()))

    def skip_lines(self) -> list:
        """Return one warning line per skip cause, with an example."""
        return [f'skipped {n} scan(s)/message(s): {cause}, e.g. {self.examples[cause]}'
                for cause, n in sorted(self.skipped.items())]

    def nothing_mapped(self) -> str:
        """Say why no scan reached the map (the main cause and an example)."""
        announced = self.extra.get('scans_announced', self.scans)
        what = self.skips() or (f'read {self.scans} of {announced} scans, damaged?'
                                if self.scans < announced else 'no scans')
        cause = max(self.skipped, key=self.skipped.get) if self.skipped else None
        return (f'no scan could be mapped ({what})'
                + (f'; e.g. {self.examples[cause]}' if cause else ''))

    def summary(self, path: str, stats: dict) -> str:
        """One line a person reads after a replay (``stats`` as written to the map JSON)."""
        mean = stats['mean_distance']
        skips = self.skips()
        return (f"wrote {path}: {stats['segments']} segments in {stats['polylines']} polylines "
                f"from {stats['points']} points of {self.used} scans"
                + (f' ({skips} skipped)' if skips else '')
                + (f', mean distance {mean * 100:.2f} cm, p95 '
                   f"{stats['p95_distance'] * 100:.2f} cm, coverage "
                   f"{stats['coverage_0_10m'] * 100:.1f}%" if mean is not None else '')
                + (f", update median {stats['update_ms_median']:.1f} ms, p99 "
                   f"{stats['update_ms_p99']:.1f} ms" if stats['updates'] else '')
                + f", {stats.get('total_seconds', self.seconds):.1f} s")


class Replay:
    """
    Feed records one by one (``feed``), then ``finish()`` for the result.

    Records: ``Scan`` (with or without ``pose``), ``Transform``, ``Odometry``, ``Skipped``.
    """

    def __init__(self, config: IncrementalConfig = None, options: ReplayOptions = None,
                 max_pending: int = 200, mapping: bool = True):
        self.options = options or ReplayOptions()
        self.mapping = bool(mapping)
        self.warnings = []
        self.description = ''
        self.mapper = IncrementalMapper(config)
        self.poses = PoseResolver(self.options)
        self.max_pending = int(max_pending)
        self._pending = deque()
        self._points = []
        self._ms = []
        self.scans = 0
        self.used = 0
        self.skipped = Counter()
        self.examples = {}
        self._t0 = time.perf_counter()

    def feed(self, record) -> None:
        """Take one record; scans are mapped as soon as their pose can be known."""
        if isinstance(record, Scan):
            self.scans += 1
            if (self.scans - 1) % self.options.every:
                return
            try:                    # the node's check, before any pose lookup
                with np.errstate(invalid='ignore', over='ignore'):
                    check_scan(record.ranges, record.angle_min, record.angle_increment,
                               record.range_min, record.range_max)
            except ScanError as exc:
                self._skip(f'bad scan: {exc.cause}', str(exc))
                return
            self._pending.append(record)
        elif isinstance(record, Skipped):
            self._skip(f'undecodable message on {record.topic}', record.reason)
            return
        else:
            try:
                with np.errstate(over='ignore', invalid='ignore'):
                    self.poses.add(record)
            except ReplayError:
                raise
            except ValueError as exc:
                self._skip('bad transform or odometry', str(exc))
                return
        self._drain(final=False)

    def feed_all(self, records: Iterable, progress=None) -> 'ReplayResult':
        """Feed every record, calling ``progress()`` after each scan; return ``finish()``."""
        for rec in records:
            self.feed(rec)
            if progress is not None and isinstance(rec, Scan):
                progress(self)
        return self.finish()

    def finish(self) -> ReplayResult:
        """Map the scans still waiting for a pose (or skip them) and return the result."""
        self._drain(final=True)
        pts = np.concatenate(self._points) if self._points else np.zeros((0, 2))
        return ReplayResult(self.mapper, pts, self.scans, self.used, Counter(self.skipped),
                            dict(self.examples), np.array(self._ms), self.poses.fixed_frame,
                            time.perf_counter() - self._t0)

    def _skip(self, cause: str, example: str) -> None:
        self.skipped[cause] += 1
        self.examples.setdefault(cause, example)

    def _drain(self, final: bool) -> None:
        while self._pending:
            scan = self._pending[0]
            give_up = (final or len(self._pending) > self.max_pending
                       or self.poses.latest >= scan.stamp + self.options.wait)
            if scan.pose is None and not give_up and self.poses.latest < scan.stamp:
                return          # wait for pose data at or after the scan's stamp
            try:
                pose = self.poses.pose(scan)
            except TransformLookupError as exc:
                if exc.curable and not give_up:
                    return
                self._pending.popleft()
                self._skip(f'no pose: {exc.cause}', str(exc))
                continue
            except ValueError as exc:
                self._pending.popleft()
                self._skip('bad scan', str(exc))
                continue
            self._pending.popleft()
            self._map(scan, pose)

    def _map(self, scan: Scan, pose: PlanarPose) -> None:
        t0 = time.perf_counter()
        try:
            with np.errstate(invalid='ignore', over='ignore'):
                pts = scan_to_points(scan.ranges, pose.beam_angles(scan.angles()), pose.xyz,
                                     scan.range_min, scan.range_max)
        except ValueError as exc:
            self._skip('bad scan', str(exc))
            return
        if not self.mapping:
            if len(pts):
                self.used += 1
                self._points.append(pts)
            else:
                self._skip('no valid points', f'scan at {scan.stamp:.3f} s')
            return
        info = self.mapper.update(pts, ordered=True, origin=pose.xyz[:2])
        dt = time.perf_counter() - t0
        if info.skipped == 'no valid points':
            self._skip('no valid points', f'scan at {scan.stamp:.3f} s')
            return
        self.used += 1
        self._points.append(pts)
        if info.skipped is None:
            self._ms.append(1000.0 * dt)


@dataclass
class Source:
    """An opened input: its records, how many scans it holds, and a description."""

    records: Iterator
    scan_count: int
    description: str
    warnings: list = field(default_factory=list)


@contextmanager
def open_input(path: str, scan_topic: str = None, odom_topic: str = None,
               pose_source: str = 'tf', period: float = 1.0) -> Iterator[Source]:
    """
    Open a bag or a CARMEN log as a stream of records (context manager yielding a Source).

    Raises ValueError (BagError for bags) with one line when the input cannot be used.
    """
    from .formats.bag import BagReader, is_bag
    from .formats.convert import carmen_messages, is_carmen, read_for_messages
    if is_carmen(path):
        log, stamps, warnings = read_for_messages(path, period, scan_topic, odom_topic)
        records = (one for _, rec, _ in carmen_messages(log, stamps)
                   for one in (rec if isinstance(rec, list) else [rec]))
        desc = f'CARMEN log, {len(log.records)} scans'
        if log.skipped:
            desc += f', {log.skipped} malformed record(s) skipped'
        yield Source(records, len(log.records), desc, warnings)
        return
    if not os.path.exists(path):
        raise ValueError(f'{path}: no such file or folder')
    if not is_bag(path):
        raise ValueError(f'{path}: unknown input type (expected a rosbag2 folder, .db3, .mcap, '
                         '.bag, or a CARMEN .log / .log.gz)')
    with BagReader(path, scan_topic, odom_topic, odometry=pose_source == 'odom') as bag:
        desc = f'bag, {bag.scan_count} scans on {bag.scan_topic}'
        warnings = []
        if pose_source == 'tf' and not bag.tf_topics:
            warnings.append(f'{path}: no /tf or /tf_static topic; scans cannot be placed '
                            '(try --pose-source odom)')
        yield Source(bag.records(), bag.scan_count, desc, warnings)


def run_replay(path: str, config: IncrementalConfig = None, options: ReplayOptions = None,
               scan_topic: str = None, odom_topic: str = None, progress: bool = False,
               mapping: bool = True) -> ReplayResult:
    """
    Replay a bag or CARMEN log through the incremental mapper; return the result.

    ``progress`` shows a tqdm bar over the scans (on a terminal). With ``mapping=False`` the
    scans are only registered (points and counts, empty map).
    """
    options = options or ReplayOptions()
    with open_input(path, scan_topic, odom_topic, options.pose_source) as source:
        replay = Replay(config, options, mapping=mapping)
        replay.warnings = list(source.warnings)
        replay.description = source.description
        bar = None
        if progress:
            import sys
            from tqdm import tqdm
            bar = tqdm(total=source.scan_count, desc='replay', unit='scan', leave=False,
                       disable=None, file=sys.stderr)

        def tick(rep):
            bar.update(1)
            if rep.scans % 25 == 0:
                bar.set_postfix(segments=len(rep.mapper.segments))
        try:
            result = replay.feed_all(source.records, tick if bar is not None else None)
        finally:
            if bar is not None:
                bar.close()
    result.extra.update(input=os.path.basename(os.path.normpath(path)),
                        input_type=source.description, pose_source=options.pose_source,
                        every=int(options.every), scans_announced=int(source.scan_count))
    if result.scans < source.scan_count:
        replay.warnings.append(f'{path}: read {result.scans} of the {source.scan_count} scans '
                               'the input announces (damaged?)')
    result.warnings = replay.warnings
    return result
