"""
Worlds of straight walls and circular arcs, with exact ray casting.

A world is a set of zero-thickness walls (segments) and arcs (a circle between two angles; a
full circle is a round pillar). Ray casting is exact and vectorised over beams and walls.

A world may also change with time (``World.dynamic``): walls that are there until some time and
then gone (``Removed``: a door leaf that opens, a box carried away) and people walking
(``Walker``: a circle moving along a path). ``World.cast`` with a time ``t`` casts against the
static walls and arcs plus whatever is there at ``t``; without ``t`` (or with no dynamic
objects) it is exactly the static cast, so static drives stay bit for bit what they were.
"""

from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import wrap_angle


@dataclass
class Arc:
    """A circular wall: centre (m), radius (m), counter-clockwise from start to end (rad)."""

    centre: tuple
    radius: float
    start: float = 0.0
    end: float = 2 * np.pi

    def points(self, step: float = 0.01) -> np.ndarray:
        """Points along the arc, at most ``step`` metres apart, shape (M, 2)."""
        n = max(2, int(np.ceil(self.radius * (self.end - self.start) / step)) + 1)
        a = np.linspace(self.start, self.end, n)
        return np.stack([self.centre[0] + self.radius * np.cos(a),
                         self.centre[1] + self.radius * np.sin(a)], axis=1)


@dataclass
class Removed:
    """
    Walls (W, 2, 2) that stand until time ``until`` (s) and are gone from then on.

    With ``since`` they are put down at that time (s) and stand from then on (until
    ``until``): a box set down where the laser had seen free space.
    """

    walls: np.ndarray
    until: float
    name: str = 'removed'
    since: float = -np.inf

    def walls_at(self, t: float) -> np.ndarray:
        """Return the walls standing at time ``t``: all of them from ``since`` until ``until``."""
        return self.walls if self.since <= t < self.until else self.walls[:0]


@dataclass
class Walker:
    """
    A person: a circle of ``radius`` m walking back and forth along ``path`` at ``speed`` m/s.

    The walk starts at the first waypoint at time 0 and turns round at either end of the path;
    from time ``until`` (s) on the person has left the scene.
    """

    path: list
    speed: float = 1.0
    radius: float = 0.25
    until: float = np.inf
    name: str = 'walker'

    def centre(self, t: float) -> np.ndarray:
        """Return the walker's position at time ``t`` (s), metres, shape (2,)."""
        wp = np.asarray(self.path, dtype=np.float64)
        step = np.hypot(*np.diff(wp, axis=0).T)
        total = float(step.sum())
        if total == 0:
            return wp[0].copy()
        s = np.mod(self.speed * t, 2 * total)
        s = 2 * total - s if s > total else s          # back on the way home
        cum = np.concatenate([[0.0], np.cumsum(step)])
        i = int(np.clip(np.searchsorted(cum, s, 'right') - 1, 0, len(step) - 1))
        f = (s - cum[i]) / step[i] if step[i] > 0 else 0.0
        return wp[i] + f * (wp[i + 1] - wp[i])

    def track(self, step: float = 0.05) -> np.ndarray:
        """Return points along the walked path, at most ``step`` m apart, (M, 2)."""
        return path_poses(self.path, step)[:, :2]


def _cast_walls(walls: np.ndarray, o: np.ndarray, d: np.ndarray) -> tuple:
    """
    Nearest hit of each ray on ``walls``: (dist (B,), index (B,), -1 and inf for none).

    ``o``: one origin (2,) or one per ray (B, 2).
    """
    b = len(d)
    a = walls[:, 0]
    e = walls[:, 1] - a
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    w = a[None, :, :] - (o[:, None, :] if o.ndim == 2 else o)
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
        s = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / den
    ok = (np.abs(den) > 1e-12) & (t > 1e-9) & (s >= 0) & (s <= 1)
    t = np.where(ok, t, np.inf)
    j = np.argmin(t, axis=1)
    best = t[np.arange(b), j]
    return best, np.where(np.isfinite(best), j, -1)


def _cast_arc(arc: Arc, o: np.ndarray, d: np.ndarray, best: np.ndarray, hit: np.ndarray,
              index: int) -> tuple:
    """Rays against one arc: the nearer of ``best`` and the arc, ``hit`` set to ``index``."""
    oc = o - np.asarray(arc.centre, dtype=np.float64)
    # Element-wise, not BLAS (d @ oc): BLAS kernels differ by CPU in the last bit, and a
    # drive simulated on one machine must be bit for bit the drive on another.
    bq = d[:, 0] * oc[..., 0] + d[:, 1] * oc[..., 1]
    cq = oc[..., 0] * oc[..., 0] + oc[..., 1] * oc[..., 1] - arc.radius ** 2
    disc = bq ** 2 - cq
    root = np.sqrt(np.maximum(disc, 0.0))
    for t in (-bq - root, -bq + root):
        p = oc + t[:, None] * d
        ang = np.mod(np.arctan2(p[:, 1], p[:, 0]) - arc.start, 2 * np.pi)
        on = (disc >= 0) & (t > 1e-9) & (ang <= arc.end - arc.start + 1e-12)
        closer = on & (t < best)
        best = np.where(closer, t, best)
        hit = np.where(closer, index, hit)
    return best, hit


@dataclass
class World:
    """Walls (W, 2, 2) and arcs; ``path`` is a list of (x, y) waypoints for a drive through it."""

    walls: np.ndarray
    arcs: list = field(default_factory=list)
    path: list = field(default_factory=list)
    name: str = 'world'

    dynamic: list = field(default_factory=list)
    """Objects that change with time (``Removed``, ``Walker``); ``cast`` sees them at ``t``."""

    def dynamic_ids(self) -> list:
        """Return the hit ids of each dynamic object, in order: a list of int arrays."""
        out, n = [], len(self.walls) + len(self.arcs)
        for obj in self.dynamic:
            k = len(obj.walls) if isinstance(obj, Removed) else 1
            out.append(np.arange(n, n + k))
            n += k
        return out

    def cast(self, origin, directions: np.ndarray, t: float = None) -> tuple:
        """
        Cast rays, at time ``t`` (s) when the world has dynamic objects.

        ``origin``: one for every ray (2,), or one per ray (B, 2) (a moving sensor).

        Returns
        -------
        dist : (B,) metres to the first hit (inf for no hit).
        hit : (B,) index of the hit object: walls are 0..W-1, arcs W..W+A-1, then the dynamic
            objects' parts in order (``dynamic_ids``); -1 for no hit.

        """
        o = np.asarray(origin, dtype=np.float64)
        d = np.asarray(directions, dtype=np.float64)
        b = len(d)
        best = np.full(b, np.inf)
        hit = np.full(b, -1, dtype=np.intp)
        if len(self.walls):
            best, hit = _cast_walls(self.walls, o, d)
        for k, arc in enumerate(self.arcs):
            best, hit = _cast_arc(arc, o, d, best, hit, len(self.walls) + k)
        if t is None or not self.dynamic:
            return best, hit
        for obj, ids in zip(self.dynamic, self.dynamic_ids()):
            if isinstance(obj, Removed):
                walls = obj.walls_at(t)
                if len(walls):
                    dist, j = _cast_walls(walls, o, d)
                    closer = dist < best
                    best = np.where(closer, dist, best)
                    hit = np.where(closer, ids[0] + j, hit)
            elif t < obj.until:
                best, hit = _cast_arc(Arc(tuple(obj.centre(t)), obj.radius), o, d, best, hit,
                                      int(ids[0]))
        return best, hit

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance from each point to the nearest wall or arc, metres, shape (N,)."""
        from ..core.index import nearest_distance
        d = np.full(len(points), np.inf)
        if len(self.walls):
            d, _ = nearest_distance(points, self.walls)
        for arc in self.arcs:
            oc = points - np.asarray(arc.centre)
            ang = np.mod(np.arctan2(oc[:, 1], oc[:, 0]) - arc.start, 2 * np.pi)
            inside = ang <= arc.end - arc.start
            radial = np.abs(np.hypot(oc[:, 0], oc[:, 1]) - arc.radius)
            ends = arc.points(step=max(arc.radius * (arc.end - arc.start), 1e-6))[[0, -1]]
            to_end = np.min(np.linalg.norm(points[:, None] - ends[None], axis=2), axis=1)
            d = np.minimum(d, np.where(inside, radial, to_end))
        return d


MAX_POSES = 1e6
"""The most poses ``path_poses`` lays (an API audit: a step of 1e-9 m asked for 45 GiB)."""


def path_poses(waypoints, step: float, turn: float = None) -> np.ndarray:
    """
    Poses every ``step`` metres along a polyline of waypoints, heading along the path.

    ``turn`` (rad): at each waypoint the robot stops and turns in place towards the next leg,
    at most this much per pose (a robot rotating in place); None: it takes the new heading in
    one pose, without stopping.

    Returns
    -------
    (P, 3) array of x, y, yaw (m, m, rad).

    """
    wp = np.asarray(waypoints, dtype=np.float64)
    if wp.ndim != 2 or wp.shape[1] != 2 or len(wp) < 2 or not np.isfinite(wp).all():
        raise ValueError(f'waypoints must be at least 2 finite (x, y), got shape {wp.shape}')
    if not (np.isfinite(step) and step > 0):
        raise ValueError(f'step must be a number > 0 (m), got {step!r}')
    poses = float(np.hypot(*np.diff(wp, axis=0).T).sum()) / step
    if poses > MAX_POSES:
        raise ValueError(f'step {step!r} m gives about {poses:.3g} poses along the '
                         f'{poses * step:.1f} m path, more than {MAX_POSES:g}')
    if turn is not None and not (np.isfinite(turn) and turn > 0):
        raise ValueError(f'turn must be a number > 0 (rad), got {turn!r}')
    out = []
    for a, b in zip(wp[:-1], wp[1:]):
        v = b - a
        length = float(np.hypot(*v))
        if length == 0:
            continue
        n = max(1, int(np.ceil(length / step)))
        s = np.arange(n) / n
        yaw = np.arctan2(v[1], v[0])
        if turn is not None and out:
            before = out[-1][-1, 2]
            change = wrap_angle(yaw - before)
            k = np.arange(int(np.ceil(abs(change) / turn)))     # arrive, then turn
            turning = wrap_angle(before + change * k / max(len(k), 1))
            out.append(np.column_stack([np.full(len(k), a[0]), np.full(len(k), a[1]),
                                        turning]))
        out.append(np.column_stack([a[0] + s * v[0], a[1] + s * v[1], np.full(n, yaw)]))
    last = wp[-1]
    yaw = out[-1][-1, 2] if out else 0.0
    out.append(np.array([[last[0], last[1], yaw]]))
    return np.concatenate(out)


def _segs(*rows) -> np.ndarray:
    return np.array([[[x1, y1], [x2, y2]] for x1, y1, x2, y2 in rows], dtype=np.float64)


def office_floor() -> World:
    """
    Build a 20 m x 12 m office floor: a corridor, five rooms, 1 m doors, a curved wall, a pillar.

    The corridor runs along y in [5, 7]. Three rooms lie below it, two above. The top-right
    room's far corner is cut by a curved wall (radius 5.39 m, from (20, 9) to (17, 12), meeting
    the straight walls at 22 degree corners, bulging 0.44 m outwards); the top-left room holds a
    round pillar of radius 0.3 m. The path drives the corridor and into every room.
    """
    walls = _segs(
        (0, 0, 20, 0),            # south outer wall
        (0, 0, 0, 12),            # west outer wall
        (20, 0, 20, 9),           # east outer wall, up to the curved wall
        (0, 12, 17, 12),          # north outer wall, up to the curved wall
        (0, 5, 2.5, 5), (3.5, 5, 9, 5), (10, 5, 15.5, 5), (16.5, 5, 20, 5),   # corridor south
        (0, 7, 4.5, 7), (5.5, 7, 14, 7), (15, 7, 20, 7),                      # corridor north
        (7, 0, 7, 5), (13, 0, 13, 5),                                         # rooms below
        (10, 7, 10, 12),                                                      # rooms above
    )
    arcs = [Arc((15.0, 7.0), float(np.hypot(5.0, 2.0)), float(np.arctan2(2.0, 5.0)),
                float(np.arctan2(5.0, 2.0))),
            Arc((4.0, 9.5), 0.3)]
    path = [(1.0, 6.0), (3.0, 6.0), (3.0, 2.5), (5.0, 1.5), (3.0, 2.5), (3.0, 6.0), (9.5, 6.0),
            (9.5, 2.5), (11.5, 1.5), (9.5, 2.5), (9.5, 6.0), (16.0, 6.0), (16.0, 2.5),
            (18.5, 1.5), (16.0, 2.5), (16.0, 6.0), (14.5, 6.0), (14.5, 9.0), (17.0, 9.5),
            (14.5, 9.0), (14.5, 6.0), (5.0, 6.0), (5.0, 9.0), (7.5, 10.0), (5.0, 9.0),
            (5.0, 6.0), (1.0, 6.0)]
    return World(walls=walls, arcs=arcs, path=path, name='office_floor')


def hall_with_arc() -> World:
    """Build a 12 m x 8 m hall whose east side is a half circle of radius 4 m, driven round it."""
    walls = _segs((0, 0, 8, 0), (0, 0, 0, 8), (0, 8, 8, 8))
    arcs = [Arc((8.0, 4.0), 4.0, -np.pi / 2, np.pi / 2)]
    path = [(2.0, 2.0), (8.0, 2.0), (9.0, 4.0), (8.0, 6.0), (2.0, 6.0), (2.0, 2.0)]
    return World(walls=walls, arcs=arcs, path=path, name='hall_with_arc')


def corridor_loop(width: float = 2.0, side: float = 30.0) -> World:
    """Build a square corridor loop (outer side ``side`` m, ``width`` m wide), driven round."""
    s, w = side, width
    walls = _segs((0, 0, s, 0), (s, 0, s, s), (s, s, 0, s), (0, s, 0, 0),
                  (w, w, s - w, w), (s - w, w, s - w, s - w), (s - w, s - w, w, s - w),
                  (w, s - w, w, w))
    h = w / 2
    path = [(h, h), (s - h, h), (s - h, s - h), (h, s - h), (h, h)]
    return World(walls=walls, arcs=[], path=path, name='corridor_loop')


def office_dynamic() -> World:
    """
    Build the office floor with things that change while the robot drives (10 scans/s).

    - A person walks up and down the corridor (y = 6.4, x from 2 to 12) at 1 m/s, past its
      north wall and the robot, and leaves at t = 22 s; another one walks to and fro across the
      top-left room until t = 28 s (circles of radius 0.25 m). The robot sees where they
      walked again after they left.
    - The door of the top-left room (x 4.5-5.5 on the corridor's north wall) is shut until
      t = 20 s and open (gone) from then on, before the robot drives through it.
    - A 0.6 m x 0.4 m box stands in the corridor by its north wall (x 11.5-12.1) until
      t = 15 s and is carried away then; the robot drives past it before and after.
    """
    world = office_floor()
    door = Removed(_segs((4.5, 7.0, 5.5, 7.0)), until=20.0, name='door')
    box = Removed(_segs((11.5, 6.55, 12.1, 6.55), (12.1, 6.55, 12.1, 6.95),
                        (12.1, 6.95, 11.5, 6.95), (11.5, 6.95, 11.5, 6.55)),
                  until=15.0, name='box')
    world.dynamic = [door, box,
                     Walker([(2.0, 6.4), (12.0, 6.4)], until=22.0, name='corridor walker'),
                     Walker([(1.5, 8.0), (3.0, 11.0)], until=28.0, name='room walker')]
    world.name = 'office_dynamic'
    return world
