"""
A time-indexed tree of coordinate frames, for poses of a laser in a fixed frame (ROS-free).

``TransformBuffer2D`` keeps, per edge parent -> child, either one static transform or a short
history of stamped ones, like tf2's buffer, and answers "where was frame ``source`` in frame
``target`` at time t" as a planar pose. It is fed from /tf and /tf_static by the node (when
tf2_ros is not installed), from odometry plus a laser mount in odom mode, and from bags by the
offline replay, so live and offline poses come from the same code.

Conventions (REP 103 / REP 105): a transform parent -> child with translation t and rotation q
maps child coordinates to parent coordinates, p_parent = R(q) p_child + t. Chains are composed in
3D (translation and rotation) and projected to the plane only at the end:

- yaw is the heading of the source frame's x axis in the target's xy plane;
- ``flip`` is True when the source frame's z axis points down (a laser mounted upside down, roll
  or pitch of 180 degrees). Its beams then sweep clockwise seen from above: a beam at angle a in
  the laser frame points at yaw - a in the target frame. ``PlanarPose.beam_angles`` mirrors the
  angles, so ``scan_to_points(ranges, pose.beam_angles(angles), pose.xyz)`` is right either way;
- a source frame tilted out of the plane by more than ``max_tilt`` is refused (its scan plane
  is not the map's plane); smaller tilts are ignored (ranges are not shortened by cos(tilt)).

Dynamic edges are interpolated between the two stored stamps around t: linearly in translation
and along the shortest arc in rotation (slerp; for planar motion, the shortest arc in yaw).
A stamp outside an edge's stored range is served by the nearest stored transform when it is
within ``tolerance`` seconds of it (held, never extrapolated), and refused otherwise.

Memory and time are bounded whatever /tf carries: an edge keeps the entries of the last
``cache_seconds`` before its newest and at most ``max_entries`` of them (the newest); the tree
holds at most ``max_frames`` frames, and a transform that would add more is refused with
``FrameLimitError`` (a ValueError) while the known frames keep working. Storing the newest
transform of an edge is O(1) amortised, an out-of-order one O(log n) plus a shift bounded by
``max_entries``; a lookup is O(log n) per edge of the chain. Walks up the tree (lookups, the
loop check when a known frame is re-hung) stop after ``MAX_DEPTH`` frames: a deeper chain, only
junk /tf can build one, is refused instead of walked.

The planar helpers used to build transforms (``se2_compose``, ``se2_inverse``,
``mount_quaternion``, ``planar_transform``) live here too, so every producer of poses and
transforms (CARMEN conversion, simulated drives, odometry mode, tests) shares one version.
"""

from bisect import bisect_left
import heapq
import math
from typing import NamedTuple

import numpy as np

from .core.geometry import se2_compose, se2_inverse  # noqa: F401  (re-exported)
from .formats.records import Transform


MAX_DEPTH = 1000
"""Most frames on a chain from a frame to its root that a lookup walks (tf2's limit too)."""

MAX_TRANSLATION = 1e8
"""Largest translation (m) of a transform: beyond any geographic frame (UTM northings reach 1e7
m); composed with its inverse, 1e300 left nothing of a pose (a CARMEN laser offset of 1e300 m
mapped every scan at x = 0)."""

CURABLE = ('no_tf', 'unknown_frame', 'not_connected', 'too_new')
"""Lookup failures that newer transforms can cure: the node and replay let such a scan wait."""


class TransformLookupError(LookupError):
    """
    A pose that cannot be given; ``cause`` says why in one word.

    Causes: ``no_tf`` (no transform received at all), ``unknown_frame``, ``not_connected``
    (both frames known, in different trees), ``too_old`` / ``too_new`` (the stamp lies before /
    after the stored transforms of an edge by more than the tolerance), ``tilted`` (the source
    frame is not level), ``flipped`` (``lookup`` on an upside-down frame; use ``lookup_planar``),
    ``too_deep`` (more than MAX_DEPTH frames between a frame and its root), ``laser_frame`` (odom
    mode: a scan of another laser than the one the mount is of).
    """

    def __init__(self, cause: str, reason: str):
        super().__init__(reason)
        self.cause = cause

    @property
    def curable(self) -> bool:
        """Whether transforms still to come can cure it (the scan should wait, in order)."""
        return self.cause in CURABLE


class PlanarPose(NamedTuple):
    """Pose of a frame projected to the plane: metres, radians, and the upside-down flag."""

    x: float
    y: float
    yaw: float
    flip: bool = False

    @property
    def xyz(self) -> np.ndarray:
        """Return (x, y, yaw) as a (3,) float array, the pose form scan_to_points takes."""
        return np.array([self.x, self.y, self.yaw])

    def beam_angles(self, angles) -> np.ndarray:
        """Return beam angles (rad, laser frame) for the planar pose: negated when flipped."""
        a = np.asarray(angles, dtype=np.float64)
        return -a if self.flip else a


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Return the yaw (rad, in (-pi, pi]) of a rotation: heading of its x axis in the xy plane."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def checked_yaw(x: float, y: float, z: float, w: float) -> float:
    """Return a quaternion's yaw (``yaw_from_quaternion``); NaN unless finite and normalised."""
    try:
        _, q = _check_transform(np.zeros(3), (x, y, z, w))     # tf2's normalisation test
    except ValueError:
        return math.nan
    return yaw_from_quaternion(*q)


PLANAR_AXES = (0, 1, 5)
"""Rows / columns of x, y and yaw in a 6 x 6 pose covariance (x, y, z, roll, pitch, yaw)."""


def planar_covariance(covariance) -> np.ndarray:
    """Return the (3, 3) x, y, yaw block of a pose covariance (36 values, row-major 6 x 6)."""
    full = np.asarray(covariance, dtype=np.float64).reshape(6, 6)
    return full[np.ix_(PLANAR_AXES, PLANAR_AXES)].copy()


def pose_covariance(covariance) -> np.ndarray:
    """Return the 36 values (row-major 6 x 6) of a planar (3, 3) covariance, as AMCL fills it."""
    full = np.zeros((6, 6))
    full[np.ix_(PLANAR_AXES, PLANAR_AXES)] = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
    return full.reshape(-1)


def quaternion_from_yaw(yaw: float) -> np.ndarray:
    """Return the unit quaternion (x, y, z, w) of a rotation by ``yaw`` rad about z."""
    return np.array([0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)])


def mount_quaternion(yaw: float, upside_down: bool = False) -> np.ndarray:
    """
    Return the quaternion (x, y, z, w) of a laser mount: yaw about z, then rolled if so.

    ``yaw`` rad about z; when ``upside_down``, then rolled 180 degrees about x (the laser's
    z axis points down, its beams sweep clockwise seen from above).

    >>> mount_quaternion(0.0, upside_down=True).tolist()
    [1.0, 0.0, 0.0, 0.0]
    """
    if not upside_down:
        return quaternion_from_yaw(yaw)
    return np.array([math.cos(0.5 * yaw), math.sin(0.5 * yaw), 0.0, 0.0])


def planar_transform(stamp: float, parent: str, child: str, pose, static: bool = False,
                     quaternion=None) -> Transform:
    """
    Return the Transform record parent -> child of a planar ``pose`` (x, y, yaw) at ``stamp``.

    z is 0; the rotation is ``quaternion`` (x, y, z, w) when given (e.g. ``mount_quaternion``
    of an upside-down laser), else the yaw about z.
    """
    q = (quaternion_from_yaw(float(pose[2])) if quaternion is None
         else np.asarray(quaternion, dtype=np.float64))
    return Transform(float(stamp), parent, child, np.array([pose[0], pose[1], 0.0]), q, static)


def quaternion_matrix(q) -> np.ndarray:
    """Return the (3, 3) rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """Interpolate unit quaternions along the shortest arc, s in [0, 1]."""
    dot = float(q0 @ q1)
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(dot)
    return (math.sin((1 - s) * theta) * q0 + math.sin(s * theta) * q1) / math.sin(theta)


def _check_transform(translation, quaternion) -> tuple:
    t = np.asarray(translation, dtype=np.float64).ravel()
    q = np.asarray(quaternion, dtype=np.float64).ravel()
    if t.shape != (3,) or not np.isfinite(t).all():
        raise ValueError(f'translation must be 3 finite numbers, got {t.tolist()}')
    if np.abs(t).max() > MAX_TRANSLATION:
        raise ValueError(f'translation {t.tolist()} lies beyond +-{MAX_TRANSLATION:g} m')
    if q.shape != (4,) or not np.isfinite(q).all():
        raise ValueError(f'quaternion must be 4 finite numbers (x, y, z, w), got {q.tolist()}')
    n2 = float(q @ q)
    if abs(n2 - 1.0) > 0.01:            # tf2's test for a denormalised quaternion
        raise ValueError(f'quaternion {q.tolist()} is not normalised (norm {math.sqrt(n2):.4f})')
    return t, q / math.sqrt(n2)


class FrameLimitError(ValueError):
    """A transform refused because it would add frames beyond the buffer's ``max_frames``."""


class _Edge:
    """
    Transforms parent -> child: one static entry, or stamped entries in time order.

    ``stamps[start:]`` and ``data[start:]`` are the live entries; dropping the oldest only
    moves ``start``, and the dead head is cut off once it is as long as the live part, so
    appending the newest entry and dropping the oldest are O(1) amortised.
    """

    __slots__ = ('parent', 'static', 'stamps', 'data', 'start')

    def __init__(self, parent: str, static: bool):
        self.parent = parent
        self.static = static
        self.stamps = []
        self.data = []            # (translation (3,), quaternion (4,)) per stamp
        self.start = 0

    def __len__(self) -> int:
        return len(self.stamps) - self.start

    def insert(self, stamp: float, t: np.ndarray, q: np.ndarray, cache: float,
               cap: int) -> None:
        if self.static:
            self.stamps, self.data = [stamp], [(t, q)]
            return
        s, lo = self.stamps, self.start
        if len(s) == lo or stamp > s[-1]:
            s.append(stamp)                  # the common case: the newest so far
            self.data.append((t, q))
        else:
            i = bisect_left(s, stamp, lo)
            if s[i] == stamp:
                self.data[i] = (t, q)        # same stamp again: the newer message wins
                return
            s.insert(i, stamp)               # late: shift at most ``cap`` entries
            self.data.insert(i, (t, q))
        lo = max(bisect_left(s, s[-1] - cache, lo), len(s) - cap)
        if lo > self.start:
            self.start = lo
            if 2 * lo >= len(s):
                del s[:lo]
                del self.data[:lo]
                self.start = 0

    def at(self, stamp: float, tolerance: float, child: str) -> tuple:
        """Return translation and rotation matrix at ``stamp`` (or TransformLookupError)."""
        if self.static:
            t, q = self.data[0]
            return t, quaternion_matrix(q)
        s, lo = self.stamps, self.start
        n = len(s)
        i = bisect_left(s, stamp, lo)
        if i < n and s[i] == stamp:
            t, q = self.data[i]
        elif lo < i < n:
            (t0, q0), (t1, q1) = self.data[i - 1], self.data[i]
            u = (stamp - s[i - 1]) / (s[i] - s[i - 1])
            t, q = t0 + u * (t1 - t0), slerp(q0, q1, u)
        elif i == lo and s[lo] - stamp <= tolerance:
            t, q = self.data[lo]
        elif i == n and stamp - s[-1] <= tolerance:
            t, q = self.data[-1]
        else:
            old = i == lo
            gap = s[lo] - stamp if old else stamp - s[-1]
            raise TransformLookupError(
                'too_old' if old else 'too_new',
                f'transform {self.parent} -> {child}: stamp {stamp:.3f} is {gap:.3f} s '
                f'{"before the oldest" if old else "after the newest"} stored '
                f'({s[lo] if old else s[-1]:.3f}), more than the tolerance {tolerance:g} s')
        return t, quaternion_matrix(q)


class TransformBuffer2D:
    """
    A tree of frames with stamped (or static) transforms on its edges; planar pose lookups.

    >>> buf = TransformBuffer2D()
    >>> buf.set_transform('base_link', 'laser', 0.0, (0.2, 0, 0.3), (0, 0, 0, 1), static=True)
    >>> buf.set_transform('odom', 'base_link', 1.0, (1, 2, 0), quaternion_from_yaw(0.5))
    >>> buf.lookup('odom', 'laser', 1.0).round(3).tolist()    # (x, y, yaw) of the laser in odom
    [1.176, 2.096, 0.5]
    """

    def __init__(self, cache_seconds: float = 30.0, max_entries: int = 10000,
                 max_frames: int = 10000):
        """
        Make an empty buffer.

        Parameters
        ----------
        cache_seconds : float
            Seconds of history kept per dynamic edge, before its newest transform.
        max_entries : int
            Most transforms kept per dynamic edge (the newest), whatever their rate: 10000
            holds 30 s at 333 Hz. Bounds memory and the cost of a late insert.
        max_frames : int
            Most frames in the tree. A transform that would add a frame beyond it is refused
            with FrameLimitError (a ValueError): junk frame names cannot grow memory without
            bound, and the frames already known keep working.

        """
        if not (math.isfinite(cache_seconds) and cache_seconds > 0):
            raise ValueError(f'cache_seconds must be a finite number > 0, got {cache_seconds!r}')
        for name, value in (('max_entries', max_entries), ('max_frames', max_frames)):
            if isinstance(value, bool) or int(value) != value or value < 2:
                raise ValueError(f'{name} must be an integer >= 2, got {value!r}')
        self.cache_seconds = float(cache_seconds)
        self.max_entries = int(max_entries)
        self.max_frames = int(max_frames)
        self._edges = {}          # child -> _Edge
        self._frames = {}         # frame -> number of edges naming it (as child or parent)
        self._newest = -math.inf  # the newest dynamic stamp stored
        self._swept = -math.inf   # ``_newest`` when expired frames were last looked for

    # -- filling -------------------------------------------------------------------------------
    def set_transform(self, parent: str, child: str, stamp: float, translation, quaternion,
                      static: bool = False) -> None:
        """
        Store the transform parent -> child (child coordinates to parent) at ``stamp`` (s).

        A frame has one parent. A transform naming a new parent for a known child replaces the
        child's history (the tree is re-hung), as does switching an edge between static and
        dynamic, but a dynamic transform never replaces a static parent: a stray publisher of
        a second parent (``other -> laser`` beside the mount ``base_link -> laser``) would drop
        a mount that comes once, on transient-local /tf_static, for good. Raises ValueError on
        empty or equal frame names, a second parent for a static frame, a loop in the tree, a
        non-finite stamp or translation, one beyond MAX_TRANSLATION, or a quaternion whose
        norm is not 1 (+-1 %), and FrameLimitError (a ValueError) when the transform would add
        a frame beyond ``max_frames`` (dynamic frames whose transforms all lie more than
        ``cache_seconds`` before the newest are dropped first: a tracker's one-off frames).
        """
        parent, child = _frame(parent), _frame(child)
        if not parent or not child:
            raise ValueError(f'frame ids must not be empty (parent {parent!r}, child {child!r})')
        if parent == child:
            raise ValueError(f'a transform from frame {parent!r} to itself')
        if not math.isfinite(stamp):
            raise ValueError(f'stamp must be finite, got {stamp!r}')
        t, q = _check_transform(translation, quaternion)
        edge = self._edges.get(child)
        if edge is not None and edge.static and not static:
            raise ValueError(f'transform {parent} -> {child} refused: {child!r} has the static '
                             f'parent {edge.parent!r} (a frame has one parent; a second '
                             f'publisher of {child!r}?)' if edge.parent != parent else
                             f'transform {parent} -> {child} refused: it is static (on '
                             '/tf_static), not dynamic')
        if not static and stamp > self._newest:
            self._newest = float(stamp)
        if edge is None or edge.parent != parent or edge.static != bool(static):
            new = (child not in self._frames) + (parent not in self._frames)
            if new and len(self._frames) + new > self.max_frames:
                self._drop_expired()
            if new and len(self._frames) + new > self.max_frames:
                raise FrameLimitError(
                    f'transform {parent} -> {child} refused: the tree already holds '
                    f'{len(self._frames)} frames, the limit (max_frames)')
            # Only a known frame can close a loop: a new one has no descendants.
            if child in self._frames and child in self._ancestors(parent, FrameLimitError):
                raise ValueError(f'transform {parent} -> {child} would close a loop in the tree')
            if edge is not None:
                self._unlink(edge.parent, child)
            edge = self._edges[child] = _Edge(parent, bool(static))
            for name in (parent, child):
                self._frames[name] = self._frames.get(name, 0) + 1
        edge.insert(float(stamp), t, q, self.cache_seconds, self.max_entries)

    def _drop_expired(self) -> None:
        """
        Drop the dynamic edges whose transforms all lie ``cache_seconds`` before the newest.

        At most once per ``cache_seconds / 10`` of data time, so a flood of new frame names at
        the limit costs one pass over the edges, not one per message.
        """
        if self._newest - self._swept < 0.1 * self.cache_seconds:
            return
        self._swept = self._newest
        old = self._newest - self.cache_seconds

        def expired(e):
            return not e.static and e.stamps and e.stamps[-1] < old
        # (a frame that is the parent of a transform still in use keeps its own)
        parents = {e.parent for e in self._edges.values() if not expired(e)}
        for child, edge in list(self._edges.items()):
            if expired(edge) and child not in parents:
                del self._edges[child]
                self._unlink(edge.parent, child)

    def _unlink(self, parent: str, child: str) -> None:
        """Drop the references of edge parent -> child from the frame counts."""
        for name in (parent, child):
            left = self._frames[name] - 1
            if left:
                self._frames[name] = left
            else:
                del self._frames[name]

    def clear(self, keep_static: bool = False) -> None:
        """Forget every transform (or every dynamic one, e.g. after the clock jumped back)."""
        self._newest = self._swept = -math.inf
        if keep_static:
            for child, edge in list(self._edges.items()):
                if not edge.static:
                    del self._edges[child]
                    self._unlink(edge.parent, child)
        else:
            self._edges.clear()
            self._frames.clear()

    def frames(self) -> set:
        """Return the names of every known frame."""
        return set(self._frames)

    def entries(self) -> int:
        """Return the number of stored transforms (over all edges)."""
        return sum(len(e) for e in self._edges.values())

    def stamps(self, child: str) -> list:
        """Return the stored stamps of the edge above ``child`` (s, ascending; none if static)."""
        edge = self._edges.get(_frame(child))
        if edge is None or edge.static:
            return []
        return edge.stamps[edge.start:]

    def still(self, child: str, count: int) -> bool:
        """Whether the newest ``count`` transforms of the edge above ``child`` are the same."""
        edge = self._edges.get(_frame(child))
        if edge is None or edge.static:
            return True
        data = edge.data[max(len(edge.data) - int(count), edge.start):]
        t0, q0 = data[0] if data else (None, None)
        return all(np.array_equal(t, t0) and np.array_equal(q, q0) for t, q in data[1:])

    # -- queries -------------------------------------------------------------------------------
    def lookup(self, target: str, source: str, stamp: float, tolerance: float = 0.1,
               max_tilt: float = math.radians(20.0)) -> np.ndarray:
        """
        Return (x, y, yaw) of frame ``source`` in frame ``target`` at ``stamp``, shape (3,).

        Raises TransformLookupError (a LookupError) saying why when the pose cannot be given,
        including when ``source`` is upside down in ``target``: use ``lookup_planar`` for
        lasers that may be mounted upside down.
        """
        pose = self.lookup_planar(target, source, stamp, tolerance, max_tilt)
        if pose.flip:
            raise TransformLookupError(
                'flipped', f'frame {source!r} is upside down in {target!r}: use lookup_planar(), '
                'whose flip flag mirrors the beam angles')
        return pose.xyz

    def lookup_planar(self, target: str, source: str, stamp: float, tolerance: float = 0.1,
                      max_tilt: float = math.radians(20.0)) -> PlanarPose:
        """
        Return the planar pose of frame ``source`` in frame ``target`` at ``stamp`` (s).

        ``tolerance`` (s): how far outside an edge's stored stamps the nearest transform is still
        used. ``max_tilt`` (rad): largest angle between the source's z axis and the target's
        (or its opposite, for an upside-down frame). Raises TransformLookupError naming the
        cause: no transforms, an unknown frame, frames in different trees, a stamp out of range,
        or a tilted frame.
        """
        rot, trans = self.lookup_matrix(target, source, stamp, tolerance)
        return planar_pose(rot, trans, max_tilt, f'frame {source!r} in {target!r}')

    def lookup_matrix(self, target: str, source: str, stamp: float,
                      tolerance: float = 0.1) -> tuple:
        """Return the transform source -> target at ``stamp``: rotation (3, 3), shift (3,)."""
        target, source = _frame(target), _frame(source)
        if not math.isfinite(stamp):
            raise ValueError(f'stamp must be finite, got {stamp!r}')
        if not self._edges:
            raise TransformLookupError('no_tf', 'no transforms received yet')
        frames = self._frames
        for name in (target, source):
            if name not in frames:
                raise TransformLookupError(
                    'unknown_frame', f'frame {name!r} is unknown (known: '
                    f'{", ".join(heapq.nsmallest(12, frames))}'
                    f'{" ..." if len(frames) > 12 else ""})')
        if target == source:
            return np.eye(3), np.zeros(3)
        up_s, up_t = self._ancestors(source), self._ancestors(target)     # at most MAX_DEPTH
        common = set(up_t)
        lca = next((f for f in up_s if f in common), None)
        if lca is None:
            raise TransformLookupError(
                'not_connected', f'frames {target!r} and {source!r} are not connected '
                f'(their roots are {up_t[-1]!r} and {up_s[-1]!r})')
        r_s, t_s = self._chain(up_s[:up_s.index(lca)], stamp, tolerance)     # source -> lca
        r_t, t_t = self._chain(up_t[:up_t.index(lca)], stamp, tolerance)     # target -> lca
        return r_t.T @ r_s, r_t.T @ (t_s - t_t)

    # -- internals -----------------------------------------------------------------------------
    def _ancestors(self, frame: str, error=None) -> list:
        """
        Return [frame, parent, grandparent, ..., root].

        A chain longer than MAX_DEPTH raises ``error`` (a ValueError class) when given, else
        TransformLookupError('too_deep'): whatever /tf holds, a walk costs at most MAX_DEPTH.
        """
        out = [frame]
        edge = self._edges.get(frame)
        while edge is not None:
            out.append(edge.parent)
            if len(out) > MAX_DEPTH:
                text = (f'frame {frame!r} has more than {MAX_DEPTH} frames above it (junk '
                        'transforms on /tf?)')
                if error is not None:
                    raise error(text)
                raise TransformLookupError('too_deep', text)
            edge = self._edges.get(edge.parent)
        return out

    def _chain(self, frames: list, stamp: float, tolerance: float) -> tuple:
        """Compose the edges above each of ``frames`` (child first): frame[0] -> top."""
        rot, trans = np.eye(3), np.zeros(3)
        for child in frames:
            t, r = self._edges[child].at(stamp, tolerance, child)
            rot, trans = r @ rot, r @ trans + t
        return rot, trans


def planar_pose(rot: np.ndarray, trans: np.ndarray, max_tilt: float = math.radians(20.0),
                what: str = 'frame') -> PlanarPose:
    """
    Project a 3D transform (rotation (3, 3), translation (3,)) to a planar pose.

    The yaw is the heading of the frame's x axis; ``flip`` says its z axis points down. Raises
    TransformLookupError('tilted') when the z axis is more than ``max_tilt`` rad from vertical.
    """
    zz = float(np.clip(rot[2, 2], -1.0, 1.0))
    tilt = math.acos(abs(zz))
    if tilt > max_tilt:
        raise TransformLookupError(
            'tilted', f'{what} is tilted {math.degrees(tilt):.1f} deg out of the plane (more '
            f'than {math.degrees(max_tilt):.1f} deg): its scans do not lie in the map plane')
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    return PlanarPose(float(trans[0]), float(trans[1]), yaw, zz < 0.0)


def planar_edge(translation, quaternion) -> PlanarPose:
    """
    Return one transform, checked as ``TransformBuffer2D.set_transform`` checks it, as planar.

    Raises ValueError (not finite, beyond MAX_TRANSLATION, a quaternion not normalised) or
    TransformLookupError('tilted') as ``planar_pose``.
    """
    t, q = _check_transform(translation, quaternion)
    return planar_pose(quaternion_matrix(q), t)


def _frame(name: str) -> str:
    """Frame ids as tf2 keeps them: no leading slash."""
    return str(name).lstrip('/')


LAG_SPAN = 1.0
"""Seconds between the two scans whose turns ``lag_costs`` compares (the matched turn against
the odometry's): long enough for a turn to show, short enough that the odometry's drift in it
is small."""
LAG_GRID = np.arange(-200, 201) * 0.005
"""The lags ``lag_costs`` tries, seconds (5 ms apart, at most a second either way)."""
LAG_CLIP = 0.1
"""Radians: a pair's disagreement counts at most this much (a wrong match, a slip)."""
LAG_EXCITED = 0.2
"""Radians the odometry's turn over a pair must change across ``LAG_GRID`` for the pair to
count: its turn rate changed within a second of its ends. Pairs of straight driving or of
a steady turn explain every lag alike and would only dilute the comparison."""


class StampLag(NamedTuple):
    """How late a laser's stamps are against the pose data, from matched turns."""

    lag: float
    """Seconds the scans are stamped after the time they were taken (negative: before); nan
    when no pair counted; +-inf when the best lag is at an end of ``LAG_GRID`` (beyond it)."""
    rms: float
    """RMS (rad) of the matched turns' disagreement with the odometry's at ``lag``."""
    rms_zero: float
    """The same with the stamps taken as they are (lag 0)."""
    pairs: float
    """Scan pairs (``LAG_SPAN`` apart, ``LAG_EXCITED``) the estimate rests on."""


def lag_costs(stamps, given_yaw, matched_yaw, since: float = -math.inf) -> tuple:
    """
    Return (cost per ``LAG_GRID`` lag, pairs, upto) of matched scans' turns against the odometry's.

    ``stamps`` (s, increasing), ``given_yaw`` and ``matched_yaw`` (rad): the laser's heading
    the pose data gave at each stamp, and the heading the scan matched at. A scan stamped
    ``lag`` seconds after it was taken is posed where the odometry was then, so over a turn its
    matched heading runs ``lag`` ahead of the odometry's at its stamp. Each pair of scans
    ``LAG_SPAN`` apart whose odometry turn depends on the lag (``LAG_EXCITED``) adds its
    squared disagreement (clipped at ``LAG_CLIP``) between the matched turn and the odometry's
    turn read ``lag`` earlier (between the scans' samples); differences, so the slow drift of
    map -> odom cancels. A pair counts only when the odometry is read inside the rows for every
    lag of the grid (not held at their ends): its later scan stamped after ``since`` and at
    most ``upto`` (the newest stamp less the grid's reach), its earlier one at least the
    grid's reach after the first row. Sums, so batches add up (``estimate_lag``): the next
    batch, with rows that reach back far enough, passes ``upto`` as its ``since``.
    Vectorised: one pass over (grid x pairs).
    """
    t = np.asarray(stamps, dtype=np.float64)
    g = np.unwrap(np.asarray(given_yaw, dtype=np.float64))
    y = np.unwrap(np.asarray(matched_yaw, dtype=np.float64))
    upto = float(t[-1] + LAG_GRID[0]) if len(t) else float(since)
    k = np.flatnonzero((t > since) & (t <= upto))
    j = np.searchsorted(t, t[k] - LAG_SPAN)
    use = ((j < k) & (t[k] - t[np.minimum(j, k)] < 2.0 * LAG_SPAN)
           & (t[np.minimum(j, k)] >= t[0] + LAG_GRID[-1]) if len(t) else j < k)
    k, j = k[use], j[use]
    shift = LAG_GRID[:, None]
    odom = np.interp(t[k] - shift, t, g) - np.interp(t[j] - shift, t, g)
    excited = np.ptp(odom, axis=0) > LAG_EXCITED if len(k) else np.zeros(0, dtype=bool)
    r = np.clip((y[k] - y[j])[excited] - odom[:, excited], -LAG_CLIP, LAG_CLIP)
    return np.sum(r * r, axis=1), int(np.count_nonzero(excited)), max(upto, float(since))


def estimate_lag(costs, pairs: float) -> StampLag:
    """Return the ``StampLag`` of summed ``lag_costs`` (the grid's best lag)."""
    costs = np.asarray(costs, dtype=np.float64)
    zero = int(np.argmin(np.abs(LAG_GRID)))
    if pairs <= 0:
        return StampLag(math.nan, math.nan, math.nan, 0.0)
    best = int(np.argmin(costs))
    rms, rms_zero = (math.sqrt(max(costs[i], 0.0) / pairs) for i in (best, zero))
    lag = (float(LAG_GRID[best]) if 0 < best < len(LAG_GRID) - 1
           else math.copysign(math.inf, LAG_GRID[best]))
    return StampLag(lag, rms, rms_zero, float(pairs))


def stamp_lag(stamps, given_yaw, matched_yaw) -> StampLag:
    """Estimate how late the scans are stamped against the pose data (``lag_costs``)."""
    costs, pairs, _ = lag_costs(stamps, given_yaw, matched_yaw)
    return estimate_lag(costs, pairs)
