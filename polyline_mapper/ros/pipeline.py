"""
The node's data path without ROS: checked scans -> queue -> poses -> points -> map updates.

ROS-free (numpy only), so it is unit-tested without DDS; the node wraps it in callbacks and a
worker thread. Scans go through in arrival order and in groups of ``update_every_n_scans``:
given the same scans and poses, the live map equals the map of an offline replay, however
the updates are timed.

- ``scan.check_scan`` validates one scan's description (REP 117 ranges, geometry, intensities) and
  returns arrays, or raises ScanError with a one-word cause.
- ``ScanPipeline.add`` (subscription callback) only queues; the queue holds at most
  ``scan_buffer_size`` scans, the oldest is dropped (counted, warned) when updates fall behind.
- ``ScanPipeline.step`` (worker) looks up each queued scan's pose at its stamp; like a tf2
  message filter, a scan whose pose may still come (no transforms yet, unknown or unconnected
  frame, stamp newer than the newest transform) waits for it up to ``transform_timeout``
  seconds, holding the scans behind it, then is skipped with its cause. It converts scans to
  fixed-frame points (upside-down lasers mirrored) and runs one incremental update per
  ``update_every_n_scans`` posed scans.
- ``WarningThrottle`` logs each cause of a skipped scan at most once per ``warning_period``,
  counting the ones suppressed in between.
"""

from collections import deque
from dataclasses import dataclass
import threading
import time
from typing import Callable, Optional

import numpy as np

from ..core.incremental import IncrementalMapper
from ..poses import TransformLookupError
from ..scan import scan_to_points, ScanArrays


class WarningThrottle:
    """Log each cause at most once per ``period`` seconds; count every occurrence."""

    def __init__(self, log: Callable[[str], None], period: float = 10.0,
                 clock: Callable[[], float] = time.monotonic):
        self.log = log
        self.period = float(period)
        self.clock = clock
        self.counts = {}
        self._last = {}
        self._since = {}
        self._lock = threading.Lock()

    def warn(self, cause: str, text: str) -> bool:
        """Count one occurrence of ``cause``; log ``text`` unless logged within the period."""
        now = self.clock()
        with self._lock:
            self.counts[cause] = self.counts.get(cause, 0) + 1
            last = self._last.get(cause)
            if last is not None and now - last < self.period:
                self._since[cause] = self._since.get(cause, 0) + 1
                return False
            more = self._since.pop(cause, 0)
            self._last[cause] = now
        suffix = f' ({more} more since the last warning of this cause)' if more else ''
        self.log(f'{text} [{cause}]{suffix}')
        return True


@dataclass
class MapSnapshot:
    """The map at one moment: segments (K, 2, 2) m, support (K,), polylines, closed flags."""

    segments: np.ndarray
    support: np.ndarray
    polylines: list
    closed: list
    header: object
    """Header of the last scan in the map (None before the first update)."""
    sigma: Optional[float]
    updates: int


class ScanPipeline:
    """
    Queue scans, give them poses and feed them to an IncrementalMapper.

    Thread-safe between one producer (``add``), one worker (``step``) and any number of
    readers (``snapshot``, ``reset``).

    ``lookup(frame_id, stamp, tolerance)`` returns the PlanarPose of the scan frame in the
    fixed frame or raises TransformLookupError; ``settings`` is a NodeSettings (replaced
    whole when parameters change at runtime).
    """

    def __init__(self, mapper: IncrementalMapper, lookup: Callable, settings,
                 warnings: WarningThrottle, info: Callable[[str], None] = print,
                 clock: Callable[[], float] = time.monotonic):
        self.mapper = mapper
        self.info = info
        self.lookup = lookup
        self.settings = settings
        self.warnings = warnings
        self.clock = clock
        self.map_lock = threading.Lock()
        self._cv = threading.Condition()
        self._pending = deque()
        self._waiting = deque()             # taken by the worker, waiting for transforms
        self._ready = []                    # posed scans' points for the next update
        self._generation = 0
        self._worker_generation = 0
        self.header = None
        self.received = 0
        self.used = 0
        self.dropped = 0
        self.updates = 0
        self.update_seconds = deque(maxlen=100000)
        self.latency_seconds = deque(maxlen=100000)
        self._estimating_logged = False

    # -- producer ------------------------------------------------------------------------------
    def add(self, scan: ScanArrays) -> None:
        """Queue a checked scan (called from the subscription callback; never blocks long)."""
        with self._cv:
            self.received += 1
            self._pending.append((scan, self.clock()))
            over = len(self._pending) + len(self._waiting) - self.settings.scan_buffer_size
            if over > 0 and self._pending:
                self._pending.popleft()
                self.dropped += 1
                dropped = True
            else:
                dropped = False
            self._cv.notify()
        if dropped:
            self.warnings.warn('queue_full', 'dropped the oldest queued scan: updates fall '
                               f'behind the scan rate (scan_buffer_size '
                               f'{self.settings.scan_buffer_size})')

    def skip(self, cause: str, text: str) -> None:
        """Count and (throttled) log a scan that is not used."""
        self.warnings.warn(cause, f'skipped scan: {text}')

    # -- worker --------------------------------------------------------------------------------
    def wait(self, timeout: float) -> None:
        """Block until a scan is queued or ``timeout`` seconds pass."""
        with self._cv:
            if not self._pending:
                self._cv.wait(timeout)

    def step(self) -> int:
        """Pose the queued scans and run the updates they complete; return how many ran."""
        s = self.settings
        with self._cv:
            gen = self._generation
            new = list(self._pending)
            self._pending.clear()
        if gen != self._worker_generation:
            self._waiting.clear()
            self._ready.clear()
            self._worker_generation = gen
        self._waiting.extend(new)
        while len(self._waiting) > s.scan_buffer_size:
            self._waiting.popleft()
            self.dropped += 1
            self.warnings.warn('queue_full', 'dropped the oldest queued scan: transforms are '
                               f'late (scan_buffer_size {s.scan_buffer_size})')
        now = self.clock()
        while self._waiting:
            scan, arrived = self._waiting[0]
            try:
                pose = self.lookup(scan.frame_id, scan.stamp, s.transform_tolerance)
            except TransformLookupError as exc:
                if exc.curable and now - arrived < s.transform_timeout:
                    break                   # its transform may still come: keep the order
                self._waiting.popleft()
                self.skip(exc.cause, f'no pose for frame {scan.frame_id!r} at '
                          f'{scan.stamp:.3f}: {exc}')
                continue
            self._waiting.popleft()
            pts = scan_to_points(scan.ranges, pose.beam_angles(scan.angles), pose.xyz,
                                 scan.range_min, scan.range_max)
            self._ready.append((pts, scan, arrived, pose.xyz[:2]))
        done = 0
        n = s.update_every_n_scans
        while len(self._ready) >= n:
            group, self._ready = self._ready[:n], self._ready[n:]
            if self._update(group, gen):
                done += 1
        return done

    def _update(self, group: list, gen: int) -> bool:
        points = np.concatenate([g[0] for g in group])
        origins = np.repeat(np.array([g[3] for g in group]), [len(g[0]) for g in group], axis=0)
        with self.map_lock:
            if gen != self._generation:
                return False                # a reset came in between: these scans are gone
            t0 = time.perf_counter()
            info = self.mapper.update(points, ordered=True, origin=origins)
            seconds = time.perf_counter() - t0
            self.used += len(group)
            self.header = group[-1][1].header
            if info.skipped is None:
                self.updates += 1
                self.update_seconds.append(seconds)
                self.latency_seconds.append(self.clock() - group[-1][2])
        if info.skipped == 'estimating noise' and not self._estimating_logged:
            self._estimating_logged = True
            self.info(
                f'estimating the noise scale from the first {self.mapper.config.noise_updates} '
                'updates; the map starts after them')
        return info.skipped is None

    # -- readers -------------------------------------------------------------------------------
    def snapshot(self) -> MapSnapshot:
        """Return the current map (ends joined into polylines) and its stamp."""
        with self.map_lock:
            geo = self.mapper.polylines()
            return MapSnapshot(geo.segments, geo.support, geo.polylines, geo.closed, self.header,
                               self.mapper.sigma, self.updates)

    def reset(self) -> int:
        """Forget the map and every queued scan; return the number of segments dropped."""
        with self._cv:
            self._generation += 1
            self._pending.clear()
        with self.map_lock:
            dropped = len(self.mapper.segments)
            self.mapper.reset()
            self.header = None
        return dropped

    def stats(self) -> dict:
        """Counters and update-time / latency percentiles (ms) so far."""
        out = {'received': self.received, 'used': self.used, 'dropped': self.dropped,
               'updates': self.updates, 'warnings': dict(self.warnings.counts)}
        for key, values in (('update_ms', self.update_seconds),
                            ('latency_ms', self.latency_seconds)):
            if values:
                v = 1e3 * np.asarray(values)
                out[key] = {'p50': float(np.percentile(v, 50)),
                            'p95': float(np.percentile(v, 95)),
                            'p99': float(np.percentile(v, 99)), 'max': float(v.max())}
        return out
