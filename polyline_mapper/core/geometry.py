"""
Segment geometry on arrays.

Conventions used across the core:

- points: ``(N, 2)`` float64 array, metres, in one fixed frame.
- segments: ``(K, 2, 2)`` float64 array, ``segments[k] = [[x1, y1], [x2, y2]]``, metres.
- pairs: parallel 1-D arrays ``(pt, seg)`` naming a point and a segment that are close.

These are element-wise functions (validation, lengths, directions, projections, sampling, run
labels, SE(2) pose composition); the structures that find what is near what are in
``index.py``. Nothing here loops over points in Python.

Rows of ``(N, 2)`` and ``(K, 2, 2)`` arrays are gathered with ``np.take(a, i, axis=0)`` (and
selected with ``np.compress``) rather than ``a[i]``: for thousands of rows NumPy's general
fancy indexing is 5-10x slower on them (measured with NumPy 2.4, 2 to 16 bytes per row).
"""

import numpy as np


def as_points(points, name: str = 'points') -> np.ndarray:
    """
    Validate and convert a point set.

    Parameters
    ----------
    points : array_like, shape (N, 2)
        Finite x, y coordinates in metres.
    name : str
        Argument name used in error messages.

    Returns
    -------
    (N, 2) float64 array (a copy only when conversion is needed).

    Raises
    ------
    ValueError
        On a wrong shape, non-numeric or non-finite values.

    """
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f'{name} must be numeric, got {type(points).__name__}') from exc
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f'{name} must have shape (N, 2), got {arr.shape}')
    if not np.isfinite(arr).all():
        bad = ~np.isfinite(arr).all(axis=1)
        raise ValueError(f'{name} has {int(bad.sum())} row(s) with NaN or inf '
                         f'(first at row {int(np.argmax(bad))})')
    return arr


def config_of(value, kind: type, name: str = 'config'):
    """
    Return ``value`` if it is a ``kind`` (None: ``kind()``, the defaults); else TypeError.

    A dict or another configuration class passed by mistake failed later on a missing
    attribute (``'dict' object has no attribute 'seed'``, an API audit).
    """
    if value is None:
        return kind()
    if not isinstance(value, kind):
        raise TypeError(f'{name} must be of type {kind.__name__} (or None: the defaults), got '
                        f'{type(value).__name__}')
    return value


def is_real(value) -> bool:
    """
    Whether ``value`` is one real number, finite or not (numpy scalars too, booleans not).

    >>> is_real(np.float32(0.01)), is_real(True), is_real('0.1'), is_real(float('nan'))
    (True, False, False, True)
    """
    return (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, (bool, np.bool_)))


def is_number(value) -> bool:
    """
    Whether ``value`` is one finite real number (numpy scalars too, booleans not).

    >>> is_number(np.float32(0.01)), is_number(True), is_number('0.1'), is_number(float('inf'))
    (True, False, False, False)
    """
    return is_real(value) and bool(np.isfinite(value))


def as_segments(segments, name: str = 'segments') -> np.ndarray:
    """Validate and convert segments to a ``(K, 2, 2)`` float64 array (K may be 0)."""
    arr = np.asarray(segments, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 2, 2))
    if arr.ndim == 2 and arr.shape[1] == 4:
        arr = arr.reshape(-1, 2, 2)
    if arr.ndim != 3 or arr.shape[1:] != (2, 2):
        raise ValueError(f'{name} must have shape (K, 2, 2) or (K, 4), got {arr.shape}')
    if not np.isfinite(arr).all():
        raise ValueError(f'{name} contains NaN or inf')
    return arr


def lengths(segments: np.ndarray) -> np.ndarray:
    """Segment lengths, shape (K,), metres."""
    d = segments[:, 1] - segments[:, 0]
    return np.hypot(d[:, 0], d[:, 1])


def directions(segments: np.ndarray) -> tuple:
    """
    Return unit directions and lengths of segments.

    Returns
    -------
    u : (K, 2) unit vectors from the first to the second end point ([1, 0] for zero length).
    length : (K,) metres.

    """
    d = segments[:, 1] - segments[:, 0]
    length = np.hypot(d[:, 0], d[:, 1])
    ok = length > 0
    u = d / np.where(ok, length, 1.0)[:, None]
    if not ok.all():
        u[~ok] = (1.0, 0.0)
    return u, length


def project(points: np.ndarray, segments: np.ndarray) -> tuple:
    """
    Project points onto segments, element by element.

    Parameters
    ----------
    points : (M, 2) array
        Points, metres.
    segments : (M, 2, 2) array
        Segment m is paired with point m.

    Returns
    -------
    dist : (M,) distance from the point to the segment (not the infinite line), metres.
    along : (M,) signed position of the projection on the line, metres from the first end.
    normal : (M,) signed offset from the infinite line, metres (left of the direction > 0).

    """
    u, length = directions(segments)
    rel = points - segments[:, 0]
    along = np.einsum('ij,ij->i', rel, u)
    normal = u[:, 0] * rel[:, 1] - u[:, 1] * rel[:, 0]
    beyond = np.clip(along, 0.0, length) - along
    dist = np.hypot(normal, beyond)
    return dist, along, normal


def sample_segments(segments: np.ndarray, step: float) -> tuple:
    """
    Sample points along segments, at most ``step`` apart, end points included.

    Returns
    -------
    samples : (S, 2) metres.
    owner : (S,) index of the segment each sample lies on.

    """
    if len(segments) == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=np.intp)
    length = lengths(segments)
    n = np.maximum(1, np.ceil(length / step).astype(np.intp)) + 1
    owner = np.repeat(np.arange(len(segments)), n)
    first = np.cumsum(n) - n
    frac = (np.arange(owner.size) - first.take(owner)) / (n.take(owner) - 1)
    a = np.take(segments[:, 0], owner, axis=0)
    b = np.take(segments[:, 1], owner, axis=0)
    return a + (b - a) * frac[:, None], owner


def in_box(segments: np.ndarray, lo, hi) -> np.ndarray:
    """
    Return which segments' bounding boxes reach into the box ``lo``..``hi`` (corners, (2,)).

    >>> in_box(np.array([[[0.0, 0.0], [1.0, 1.0]], [[3.0, 3.0], [4.0, 3.0]]]), (0.5, 0.5),
    ...        (2.0, 2.0)).tolist()
    [True, False]
    """
    a, b = segments[:, 0], segments[:, 1]      # (a reduction over the two ends is ~4x slower)
    inside = (np.maximum(a, b) >= lo) & (np.minimum(a, b) <= hi)
    return inside[:, 0] & inside[:, 1]


def end_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """
    Distance between segments matched pair by pair, end to end, either way round.

    Returns
    -------
    (K,) the larger of the two end-point distances, for the better orientation, metres.

    """
    a = np.broadcast_to(a, np.broadcast_shapes(np.shape(a), np.shape(b)))
    b = np.broadcast_to(b, a.shape)
    same = np.maximum(np.linalg.norm(a[:, 0] - b[:, 0], axis=1),
                      np.linalg.norm(a[:, 1] - b[:, 1], axis=1))
    swap = np.maximum(np.linalg.norm(a[:, 0] - b[:, 1], axis=1),
                      np.linalg.norm(a[:, 1] - b[:, 0], axis=1))
    return np.minimum(same, swap)


def label_runs(flag: np.ndarray, group: np.ndarray) -> tuple:
    """
    Label runs of equal ``flag`` inside each ``group`` (items ordered by group).

    Returns
    -------
    run : (M,) run id of each item, from 0.
    n_runs : int

    """
    start = np.ones(flag.size, dtype=bool)
    start[1:] = (flag[1:] != flag[:-1]) | (group[1:] != group[:-1])
    run = np.cumsum(start) - 1
    return run, int(run[-1]) + 1 if run.size else 0


def group_minmax(values: np.ndarray, groups: np.ndarray, n_groups: int) -> tuple:
    """Per-group minimum and maximum of ``values`` (inf / -inf for empty groups)."""
    lo = np.full(n_groups, np.inf)
    hi = np.full(n_groups, -np.inf)
    np.minimum.at(lo, groups, values)
    np.maximum.at(hi, groups, values)
    return lo, hi


def se2_compose(a, b) -> np.ndarray:
    """
    Compose planar poses: ``b`` (given in ``a``'s frame) seen from ``a``'s parent frame.

    ``a``, ``b``: (..., 3) arrays of (x, y, yaw), metres and radians, broadcast against each
    other. Returns (..., 3); the yaw is not wrapped.

    >>> se2_compose((1.0, 0.0, np.pi / 2), (1.0, 0.0, 0.0)).round(12).tolist()
    [1.0, 1.0, 1.570796326795]
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1],
                     a[..., 1] + s * b[..., 0] + c * b[..., 1], a[..., 2] + b[..., 2]], axis=-1)


def wrap_angle(angle):
    """
    Wrap angles (radians; a float or an array) into [-pi, pi).

    >>> float(wrap_angle(3 * np.pi / 2)), wrap_angle(np.array([np.pi, -np.pi])).tolist()
    (-1.5707963267948966, [-3.141592653589793, -3.141592653589793])
    """
    return (angle + np.pi) % (2 * np.pi) - np.pi


def se2_inverse(a) -> np.ndarray:
    """Invert planar poses: (..., 3) arrays of (x, y, yaw) -> (..., 3), se2_compose(a, inv) = 0."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1], -a[..., 2]],
                    axis=-1)
