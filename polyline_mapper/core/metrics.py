"""The metrics reported everywhere: distances of points to the map, coverage, compression."""

import numpy as np

from .geometry import nearest_distance, PointIndex


def map_metrics(points: np.ndarray, segments: np.ndarray, index: PointIndex = None,
                coverage_radius: float = 0.10) -> dict:
    """
    Quality of a segment map over a point set.

    Returns
    -------
    dict with ``points``, ``segments``, ``mean_distance`` and ``p95_distance`` (metres, of each
    point to its nearest segment), ``coverage_0_10m`` (share of points within ``coverage_radius``
    of the map, 0..1) and ``compression`` (points / (2 x segments)).

    """
    n, k = len(points), len(segments)
    out = {'points': int(n), 'segments': int(k)}
    if n == 0 or k == 0:
        out.update(mean_distance=float('nan'), p95_distance=float('nan'), coverage_0_10m=0.0,
                   compression=float('nan'))
        return out
    d, _ = nearest_distance(points, segments, index=index, radius=0.5)
    out.update(mean_distance=float(d.mean()), p95_distance=float(np.percentile(d, 95)),
               coverage_0_10m=float(np.mean(d <= coverage_radius)),
               compression=float(n / (2.0 * k)))
    return out
