"""
Offline replay: a bag, a CARMEN log or a simulated drive through the mapping session.

``run_replay`` opens the recording (``recordings``), feeds its records in order to a
``session.MappingSession`` on data time (a scan arrives at its stamp; a scan waits for pose data
at or after its stamp, up to ``SessionOptions.wait`` seconds of newer data) and returns the map
value with the points it was made from. The node maps through the same session, so a recording
played into the live node gives the same map (``test_live_tools``).

CARMEN logs are replayed as the messages ``polyline-mapper convert`` writes into a bag
(``formats.carmen_bag.carmen_messages``): the corrected laser pose of each record reaches the
mapper through the same TF lookups, in LaserScan precision (float32 ranges and angles), so a log
and its bag give the same map.
"""

from collections import Counter
from dataclasses import dataclass, field
import os
import time
from typing import Optional

import numpy as np

from .core import map_metrics
from .core.freespace import free_space_stats
from .core.geometry import se2_compose
from .core.incremental import IncrementalConfig
from .core.loops import chain, corrections, find_loops, optimize, relative, settle
from .core.mapvalue import MapValue
from .formats.records import Odometry, Scan
from .recordings import open_recording
from .session import MappingSession, SessionError, SessionOptions

ReplayError = SessionError


@dataclass
class ReplayResult:
    """What a replay produced: the session, its map value and the points it was fed."""

    session: MappingSession
    map_value: MapValue
    """The final map; its ``stats`` hold the quality over ``points``, counts and times."""
    points: np.ndarray
    """(N, 2) every point given to the mapper, fixed frame, metres."""
    seconds: float = 0.0
    warnings: list = field(default_factory=list)
    odometry: bool = True
    """Whether the recording holds odometry (``recordings.Recording.odometry``)."""

    @property
    def mapper(self):
        """Return the incremental mapper of the session."""
        return self.session.mapper

    @property
    def used(self) -> int:
        """Return the number of scans given to the mapper."""
        return self.session.used

    @property
    def scans(self) -> int:
        """Return the number of scans read (before --every)."""
        return self.session.received

    @property
    def skipped(self) -> Counter:
        """Return the records not used, by 'category: cause'."""
        return Counter(self.session.skipped)

    @property
    def fixed_frame(self) -> Optional[str]:
        """Return the map frame."""
        return self.session.fixed_frame

    def stats(self) -> dict:
        """Return the map's statistics: quality, counts, update times."""
        return self.map_value.stats

    def skips(self) -> str:
        """Return the skipped counts as text, e.g. '3 no pose: too_new, 1 bad scan: ...'."""
        return ', '.join(f'{n} {cause}' for cause, n in sorted(self.skipped.items()))

    def skip_lines(self) -> list:
        """Return one warning line per skip cause, with an example."""
        ex = self.session.examples
        return [f'skipped {n} scan(s)/message(s): {cause}, e.g. {ex[cause]}'
                for cause, n in sorted(self.skipped.items())]

    def nothing_mapped(self) -> str:
        """Say why no scan reached the map (the main cause and an example)."""
        announced = self.map_value.stats.get('scans_announced', self.scans)
        what = self.skips() or (f'read {self.scans} of {announced} scans, damaged?'
                                if self.scans < announced else 'no scans')
        skipped = self.skipped
        cause = max(skipped, key=skipped.get) if skipped else None
        return (f'no scan could be mapped ({what})'
                + (f'; e.g. {self.session.examples[cause]}' if cause else '')
                + (self._mount_hint() or self._odometry_hint()
                   if cause and cause.startswith('no pose') else ''))

    def _odometry_hint(self) -> str:
        """Say that odometry can place scans that only static transforms reach (tf mode)."""
        if self.session.options.pose_source != 'tf' or not self.odometry:
            return ''
        if not any(c.endswith('no_tf') for c in self.skipped):
            return ''
        return ('; the recording has odometry (nav_msgs/Odometry): --pose-source odom places '
                'the robot by it, the laser on it as /tf_static mounts it')

    def _mount_hint(self) -> str:
        """Say how to place scans whose frame no transform names: by odometry and the mount."""
        options = self.session.options
        known = self.session.poses.buffer.frames()
        lost = [f for f in self.session.scan_frames if f and f not in known]
        if (options.pose_source == 'scan' or options.mount is not None or not lost
                or not self.odometry):
            return ''           # (without odometry the recording's warning names scan mode)
        odom = '' if options.pose_source == 'odom' else '--pose-source odom '
        return (f"; no transform names the scans' frame {lost[0]!r}: give the laser's pose on "
                f'the robot with {odom}--laser-mount X,Y,YAW_DEG (the odometry then places '
                'the robot)')

    def summary(self, path: str) -> str:
        """One line a person reads after a replay."""
        stats = self.map_value.stats
        mean = stats.get('mean_distance')
        skips = self.skips()
        ms = stats.get('update_ms') or {}
        return (f"wrote {path}: {stats['segments']} segments in {stats['polylines']} polylines "
                f"from {stats['points']} points of {self.used} scans"
                + (f' ({skips} skipped)' if skips else '')
                + (f', mean distance {mean * 100:.2f} cm, p95 '
                   f"{stats['p95_distance'] * 100:.2f} cm, coverage "
                   f"{stats['coverage_0_10m'] * 100:.1f}%"
                   if mean is not None and np.isfinite(mean) else '')
                + free_space_text(stats)
                + (f", update median {ms['p50']:.1f} ms, p99 {ms['p99']:.1f} ms" if ms else '')
                + loop_text(stats.get('loop_closure'))
                + f", {stats.get('total_seconds', self.seconds):.1f} s")


def loop_text(info: Optional[dict]) -> str:
    """Return ', loop closure applied (N loops)' or ', loop closure not applied: why'."""
    if not info:
        return ''
    if info.get('applied'):
        return f", loop closure applied ({info.get('kept', info.get('loops', '?'))} loops)"
    return f", loop closure not applied: {info.get('reason', 'no reason given')}"


def free_space_text(stats: dict) -> str:
    """Return ', contradicted X % of map length (N segments, B beams)' for a summary line."""
    share = stats.get('contradicted_share')
    if share is None:
        return ', no beams: free space not judged' if 'beams' in stats else ''
    return (f', contradicted {share * 100:.1f}% of map length '
            f"({stats['contradicted_segments']} segments, {stats['beams']} beams)")


REPORTED = ('time_increment', 'time_jump', 'scan_gap', 'scan_gap_given_up', 'pose_estimate',
            'pose_estimate_given_up', 'wrong_start', 'odom_jump', 'odom_reset_given_up',
            'scan_clock', 'odom_rate', 'map_frame', 'self_hits', 'not_localized')
"""Session warnings a replay prints (the first, with a count): input problems that no skip
count shows (a scan used without motion compensation, pose data dropped at a clock jump, scans
not found after a gap in them or near a pose estimate on /initialpose, a localization that
starts on a wrong place, an odometry that jumped: a driver restart, scans stamped off the
pose data's clock, odometry much slower than the scans, a saved map taken in another frame,
readings of the robot itself, a localization on a saved map whose scans stopped matching it)."""


def replay_records(records, config: IncrementalConfig = None,
                   options: SessionOptions = None, progress=None, start_map=None,
                   initial_pose=None, warn=None, matched_scans: list = None) -> MappingSession:
    """
    Map records on data time: feed them to a new session, flush it at the end, return it.

    ``progress(session)`` is called after each scan record. ``start_map``: a saved map to
    start from (a ``formats.mapjson.MapFile`` as ``read_map`` returns it, or a MapValue) with
    the robot at ``initial_pose`` (x, y, yaw; m, rad) at the first scan
    (``MappingSession.load_map``; None: where the poses say). ``warn(cause, text)``: the
    session's warnings. ``matched_scans``: a list the session fills with its matched scans
    (``MappingSession.matched_scans``; loop closure).
    """
    options = options or SessionOptions()
    session = MappingSession(config, options, warn=warn)
    session.matched_scans = matched_scans
    if start_map is not None:
        value = getattr(start_map, 'value', start_map)
        session.load_map(value, initial_pose, getattr(start_map, 'grid', None))
    for record in records:
        session.add(record)
        session.step()
        if progress is not None and isinstance(record, Scan):
            progress(session)
    session.flush()
    return session


def run_replay(path: str, config: IncrementalConfig = None, options: SessionOptions = None,
               scan_topic: str = None, odom_topic: str = None, progress: bool = False,
               mapping: bool = True, start_map=None, initial_pose=None,
               loop_closure: bool = False) -> ReplayResult:
    """
    Replay a bag, CARMEN log or ``sim:`` drive through a mapping session; return the result.

    ``progress`` shows a tqdm bar over the scans (on a terminal). With ``mapping=False`` the
    map is never changed: the scans are only registered (points, counts, poses), the map stays
    empty or, with ``start_map``, as loaded. ``start_map`` (a ``read_map`` MapFile or a
    MapValue) and ``initial_pose``: localization on a saved map (``replay_records``).
    ``loop_closure`` (scan matching from odometry, a new map): after the replay, the loops of
    its trajectory are found and closed (``close_loops``), and the recording is mapped again
    with the odometry moved onto the closed trajectory (``corrected_odometry``, without
    matching); the result is that second map, or the first when no loop beyond
    ``core.loops.BAND`` was kept (``close_loops``) or when the second map, judged both ways,
    is worse than the first (``closed_map_kept``: its beams pass through more of it, or it
    fits its own points worse); ``stats['loop_closure']`` says which.
    """
    import dataclasses
    t0 = time.perf_counter()
    options = dataclasses.replace(options or SessionOptions(), keep_points=True,
                                  mapping=mapping)
    if loop_closure and not (options.scan_matching and options.pose_source == 'odom'
                             and mapping and start_map is None):
        raise ReplayError('loop closure needs scan matching from odometry (pose source odom) '
                          'into a new map')
    noted = {}

    def warn(cause, text):
        if cause in REPORTED:
            n, first = noted.get(cause, (0, text))
            noted[cause] = (n + 1, first)
    matched = [] if loop_closure else None
    if loop_closure:
        # Both maps with the first one's free-space setting: the default window (-1) is 0 with
        # scan matching, and the second map (odometry on the closed loops, no matching) must
        # not get the evidence the first lacked, or the contradicted shares compared below
        # would judge the setting, not the closure.
        config = (config or IncrementalConfig()).resolved(options.scan_matching)
    session, source = _feed(path, config, options, scan_topic, odom_topic, progress,
                            start_map, initial_pose, warn, matched)
    value, points = _judged(session)
    if loop_closure:
        t1 = time.perf_counter()
        stamps, fix, info = close_loops(matched, session.mapper.sigma or 0.01)
        del matched[:]
        if stamps is not None:
            frame = session.map_frame       # the corrected odometry is in the map frame
            first, noted_first = (session, source, value, points), dict(noted)
            noted.clear()
            session, source = _feed(
                path, config, dataclasses.replace(options, scan_matching=False,
                                                  fixed_frame=None),
                scan_topic, odom_topic, progress, None, None, warn, None,
                lambda records: corrected_odometry(records, stamps, fix))
            value, points = _judged(session)
            value = dataclasses.replace(value, frame_id=frame)
            keep, judged = closed_map_kept(first[2].stats, value.stats)
            info.update(judged)
            if not keep:
                info.update(applied=False, reason=judged['reason'])
                session, source, value, points = first
                noted.clear()
                noted.update(noted_first)
        info['seconds'] = round(time.perf_counter() - t1, 3)
    st = value.stats
    if loop_closure:
        st['loop_closure'] = info
    ms = st.get('update_ms')
    st.update(scans_announced=int(source.scan_count),
              input=os.path.basename(os.path.normpath(path)),
              input_type=source.description, pose_source=options.pose_source,
              scan_topic=source.scan_topic,
              odom_topic=source.odom_topic if options.pose_source == 'odom' else None,
              every=int(options.every), fixed_frame=value.frame_id,
              update_ms_median=round(ms['p50'], 3) if ms else None,
              update_ms_p99=round(ms['p99'], 3) if ms else None,
              seconds=round(time.perf_counter() - t0, 3))
    if options.scan_time_offset:
        st['scan_time_offset'] = options.scan_time_offset
    if options.scan_matching and options.chord_knots != SessionOptions.chord_knots:
        st['chord_knots'] = options.chord_knots     # (they place the scans: plot --points)
    warnings = list(source.warnings) + [f'{text} ({n} time{"s" if n > 1 else ""})'
                                        for n, text in noted.values()]
    if mapping and session.used and not len(value.segments) and session.mapper.sigma is None:
        k = -(-session.used // options.update_every_n_scans)
        left = sum(session.skipped.values())
        cause = max(session.skipped, key=session.skipped.get) if left else ''
        advice = (f'{left} were skipped ({cause}: {session.skipped[cause]}, see below), which '
                  'is what to fix' if left >= session.used else
                  'give more scans, or lower noise_updates (--set noise_updates=N)')
        warnings.append(f'{path}: no segment: the mapper estimates the noise scale over its first '
                        f'{session.mapper.config.noise_updates} map updates and maps after them; '
                        f'{session.used} scan(s) made {k} update(s) (one per '
                        f'{options.update_every_n_scans} scans): {advice}')
    if session.received < source.scan_count:
        warnings.append(f'{path}: read {session.received} of the {source.scan_count} scans '
                        'the input announces (damaged?)')
    return ReplayResult(session, value, points, time.perf_counter() - t0, warnings,
                        source.odometry)


def _judged(session: MappingSession) -> tuple:
    """Return a session's (map value with its point and free-space stats, points)."""
    value = session.map_value()
    points = session.points()
    value.stats.update(map_metrics(points, value.segments))
    value.stats.update(free_space_stats(value.segments, points, session.origins()))
    return value, points


def _feed(path: str, config, options: SessionOptions, scan_topic, odom_topic, progress: bool,
          start_map, initial_pose, warn, matched, rewrite=None) -> tuple:
    """Open ``path`` and map its records (``rewrite``(records) first); (session, source)."""
    odometry = options.pose_source == 'odom'
    with open_recording(path, scan_topic, odom_topic, odometry=odometry,
                        pose_source=options.pose_source) as source:
        bar = None
        if progress:
            import sys
            from tqdm import tqdm
            bar = tqdm(total=source.scan_count, desc='replay' if rewrite is None else 'remap',
                       unit='scan', leave=False, disable=None, file=sys.stderr)

        def tick(session):
            bar.update(1)
            if session.received % 25 == 0:
                bar.set_postfix(segments=len(session.mapper.segments))
        records = source.records() if rewrite is None else rewrite(source.records())
        try:
            session = replay_records(records, config, options,
                                     tick if bar is not None else None, start_map,
                                     initial_pose, warn, matched)
        finally:
            if bar is not None:
                bar.close()
    return session, source


LOOP_KEYFRAME = (0.5, 0.3)
"""Loop closure: a matched scan is a keyframe of the pose graph when it lies this far (m, rad)
from the last keyframe (``close_loops``)."""


CLOSED_FIT = (0.005, 0.05)
"""
``closed_map_kept``: the closed map may cover (within 0.10 m) at most this share fewer of its
points, and their mean distance be at most this share larger, than the matched map's. On the
drifted logs (seeds 0-4) the closures that lowered the trajectory error left the map's own
coverage +0.6 to +1.0 points and mean distance -2 % to +1 % (Intel); the one that raised it
(CSAIL seed 0, ATE 0.219 -> 0.245 m) lowered the contradicted share 4.72 -> 4.30 % but
coverage 97.0 -> 95.0 % and mean +16 % (2026-11-29, benchmarks/README.md, "Loop closure").
"""


def closed_map_kept(matched: dict, closed: dict) -> tuple:
    """
    Judge the closed map against the matched one both ways; return (keep, what was judged).

    Kept when its own beams pass through no more of it (``contradicted_share``: doubled walls
    where the second map, placed without matching, disagrees with itself) and it fits its own
    points about as well (``coverage_0_10m``, ``mean_distance``, ``CLOSED_FIT``: a closure
    can undouble walls where its loops are and bend others off their points).
    ``matched`` and ``closed`` are the maps' stats; the dict holds both sides' numbers and,
    when not kept, the ``reason``.
    """
    keys = {'contradicted': 'contradicted_share', 'coverage': 'coverage_0_10m',
            'mean': 'mean_distance'}
    judged = {}
    for name, key in keys.items():
        judged[f'{name}_before'], judged[f'{name}_after'] = matched.get(key), closed.get(key)
    if None in judged.values():
        judged['reason'] = 'not judged'
        return False, judged
    if judged['contradicted_after'] > judged['contradicted_before']:
        judged['reason'] = 'more contradicted'
    elif (judged['coverage_after'] < judged['coverage_before'] - CLOSED_FIT[0]
          or judged['mean_after'] > judged['mean_before'] * (1.0 + CLOSED_FIT[1])):
        judged['reason'] = 'fits its points worse'
    return 'reason' not in judged, judged


def close_loops(scans: list, sigma: float) -> tuple:
    """
    Find the loops of a matched trajectory and the corrections they imply (``core.loops``).

    ``scans``: a session's ``matched_scans`` (stamp, laser pose, laser points, correction
    map -> odom), in order; ``sigma``: its map's noise scale (m). Keyframes are taken
    ``LOOP_KEYFRAME`` apart. Returns (stamps (M,), corrections (M, 3): the new map -> odom
    correction at each matched scan's stamp, yaw unwrapped; info dict: keyframes, loops found,
    active (beyond ``loops.BAND`` from the trajectory), kept after the pose graph, applied,
    and when not applied the reason). No loop beyond the band, or none kept: stamps and
    corrections are None (nothing to close).
    """
    info = {'keyframes': 0, 'loops': 0, 'active': 0, 'kept': 0, 'applied': False}
    if not scans:
        info['reason'] = 'no matched scan'
        return None, None, info
    keep, last = [], None
    for k, (_, pose, _, _) in enumerate(scans):
        if last is not None:
            step = relative(last, pose)
            if (np.hypot(step[0], step[1]) < LOOP_KEYFRAME[0]
                    and abs(step[2]) < LOOP_KEYFRAME[1]):
                continue
        keep.append(k)
        last = pose
    stamps = np.array([s[0] for s in scans])
    poses = np.array([scans[k][1] for k in keep])
    loops, active = settle(poses, find_loops(poses, [scans[k][2] for k in keep], sigma))
    info.update(keyframes=len(keep), loops=len(loops), active=int(active.sum()))
    if not active.any():
        info['reason'] = 'no loop beyond the band'
        return None, None, info
    moving = {(e.a, e.b) for e, a in zip(loops, active) if a}
    try:
        after, kept = optimize(poses, chain(poses) + loops)
    except (np.linalg.LinAlgError, ValueError):     # a singular graph: nothing is closed
        info['reason'] = 'pose graph not solved'
        return None, None, info
    if not np.isfinite(after).all():
        info['reason'] = 'pose graph not solved'
        return None, None, info
    info['kept'] = len(kept)
    if not any((e.a, e.b) in moving for e in kept):
        info['reason'] = 'no loop beyond the band kept'
        return None, None, info
    fix = corrections(poses, after, stamps[keep], stamps)
    new = se2_compose(fix, np.array([s[3] for s in scans]))
    new[:, 2] = np.unwrap(new[:, 2])
    info['applied'] = True
    return stamps, new, info


def corrected_odometry(records, stamps: np.ndarray, correction: np.ndarray):
    """
    Yield ``records`` with every Odometry record moved by the correction at its stamp.

    ``correction``: (M, 3) map -> odom at ``stamps`` (M,), interpolated between them (held
    beyond): the odometry then gives the base pose in the map frame.
    """
    for record in records:
        if isinstance(record, Odometry) and len(stamps):
            c = [np.interp(record.stamp, stamps, correction[:, k]) for k in range(3)]
            t = np.asarray(record.translation, dtype=np.float64)
            xy = se2_compose(c, (t[0], t[1], 0.0))[:2]
            h = 0.5 * c[2]
            x, y, z, w = np.asarray(record.rotation, dtype=np.float64)
            sz, cz = np.sin(h), np.cos(h)
            record = Odometry(record.stamp, record.frame_id, record.child_frame_id,
                              np.array([xy[0], xy[1], t[2]]),
                              np.array([cz * x - sz * y, cz * y + sz * x, cz * z + sz * w,
                                        cz * w - sz * z]))
        yield record
