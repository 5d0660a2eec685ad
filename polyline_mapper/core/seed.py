"""
Seeding: segments for points that no segment explains.

The paper starts from the two diagonals of the bounding box and relies on far points pulling
segments. Our E-step cuts points off beyond ``kappa * sigma`` (see ``emsf.py``), so points that no
segment reaches would never be explained; and the incremental mapper must add walls it has not
seen before. Both are served by seeding: unexplained points are binned in a square grid, and every
cell with enough point weight gets the orthogonal-regression segment of its points, trimmed to
their projections. Split, EM and merge then treat seeds like any other segment (a wall cut by the
grid is joined again by merging; a blob of clutter keeps a short segment or loses its support).
"""

import numpy as np

from .emsf import weighted_lines
from .geometry import group_minmax
from .index import cell_keys


def seed_segments(points: np.ndarray, weights: np.ndarray, cell: float,
                  min_mass: float, min_density: float = 0.0, r: float = 1.0,
                  max_thickness: float = np.inf) -> np.ndarray:
    """
    Seed segments from points, one per occupied grid cell.

    Parameters
    ----------
    points : (U, 2) array
        The unexplained points, metres.
    weights : (U,) array
        Their multiplicities.
    cell : float
        Grid cell side, metres.
    min_mass : float
        A cell needs at least this much point weight to seed a segment,
    min_density : float
        and at least this much per ``2 r`` of the seed's length.
    r : float
        The current LSS half-size, metres.
    max_thickness : float
        A cell's points must lie within this RMS distance of their line (m): a cell straddling
        a corner holds an L of points whose line is a tilted stub that would then own the
        corner; left unseeded, the corner is reached by the walls seeded beside it.

    Returns
    -------
    (S, 2, 2) metres.

    """
    if len(points) == 0:
        return np.zeros((0, 2, 2))
    _, cell_id = np.unique(cell_keys(points, cell), return_inverse=True)
    k = int(cell_id.max()) + 1
    centre, direction, mass, thick = weighted_lines(points, cell_id, weights, k,
                                                    return_thickness=True)
    rel = points - np.take(centre, cell_id, axis=0)
    dirs = np.take(direction, cell_id, axis=0)
    t = rel[:, 0] * dirs[:, 0] + rel[:, 1] * dirs[:, 1]
    lo, hi = group_minmax(t, cell_id, k)
    keep = ((mass >= min_mass) & (mass >= min_density * (hi - lo) / (2.0 * r)) & (hi > lo)
            & (thick <= max_thickness))
    c, u = centre[keep], direction[keep]
    return np.stack([c + lo[keep, None] * u, c + hi[keep, None] * u], axis=1)
