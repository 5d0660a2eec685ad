"""A cluttered simulated world for the comparison (benchmark-only, not part of the package)."""

import numpy as np
from polyline_mapper.sim import Arc, World


def _box(cx: float, cy: float, w: float, h: float, yaw: float = 0.0) -> list:
    """Return the four walls of a w x h box centred at (cx, cy), rotated by yaw (rad)."""
    c, s = np.cos(yaw), np.sin(yaw)
    corners = [(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)]
    pts = [(cx + c * x - s * y, cy + s * x + c * y) for x, y in corners]
    return [[pts[i], pts[(i + 1) % 4]] for i in range(4)]


def cluttered_room() -> World:
    """
    Build a 14 m x 10 m room full of clutter, driven round a 11 m x 4 m loop.

    Outer walls, a partition stub, a slanted wall, five boxes (one rotated 30 degrees), two round
    pillars (radius 0.25 m) and two tables of four legs (radius 4 cm) that look like point
    clutter to a laser.
    """
    walls = [[(0, 0), (14, 0)], [(14, 0), (14, 10)], [(14, 10), (0, 10)], [(0, 10), (0, 0)],
             [(7, 0), (7, 2.2)], [(12.0, 10.0), (14.0, 8.5)]]
    walls += _box(3.0, 8.5, 0.8, 0.8) + _box(10.0, 8.6, 1.0, 0.6) + _box(11.0, 1.2, 0.6, 0.6)
    walls += _box(3.5, 1.2, 1.0, 0.5) + _box(7.0, 5.0, 0.8, 0.8, np.deg2rad(30.0))
    arcs = [Arc((4.5, 5.0), 0.25), Arc((9.5, 5.0), 0.25)]
    arcs += [Arc((x, y), 0.04) for x, y in ((3.0, 4.2), (3.5, 4.2), (3.0, 4.7), (3.5, 4.7),
                                            (10.5, 5.5), (11.0, 5.5), (10.5, 6.0), (11.0, 6.0))]
    path = [(1.5, 3.0), (12.5, 3.0), (12.5, 7.0), (1.5, 7.0), (1.5, 3.0)]
    return World(walls=np.array(walls, dtype=np.float64), arcs=arcs, path=path,
                 name='cluttered_room')
