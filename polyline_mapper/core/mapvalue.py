"""
The map as one value: what every producer returns and every writer or publisher takes.

A batch fit (``MapValue.from_fit``) and the mapping session (``session.MappingSession.map``)
produce it; the node turns it into messages, ``formats.mapjson`` writes it as MAP.json, and
``formats.mapjson.read_map`` reads one back. ``support[i]`` belongs to ``segments[i]``: the
producers build both from the same array, after every filter.
"""

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .geometry import as_segments


@dataclass
class MapValue:
    """
    A polyline map: segments, their support, the polylines they form, frame, stamp and stats.

    >>> import numpy as np
    >>> m = MapValue(np.array([[[0.0, 0.0], [1.0, 0.0]]]), np.array([12.0]),
    ...              [np.array([[0.0, 0.0], [1.0, 0.0]])], [False])
    >>> len(m), m.frame_id
    (1, 'map')
    """

    segments: np.ndarray
    """(K, 2, 2) float, metres in ``frame_id``; the edges of ``polylines``."""
    support: np.ndarray
    """(K,) float: the (capped) point weight behind each segment, same order as ``segments``."""
    polylines: list
    """List of (M, 2) float vertex arrays, metres."""
    closed: list
    """One bool per polyline: whether it closes on itself."""
    frame_id: str = 'map'
    stamp: Optional[float] = None
    """Seconds: the stamp of the newest scan in the map (None for a map of bare points)."""
    stats: dict = field(default_factory=dict)
    trajectory: Optional[np.ndarray] = None
    """(P, 4) float: stamp (s), x, y, yaw (m, rad) of the robot base (the frame the laser is
    mounted on; the laser itself when it has no mount) in ``frame_id`` for each scan in the
    map, where the mapper placed it (None when not recorded)."""

    def __post_init__(self):
        """Check the arrays: finite segments and trajectory, support and flags that agree."""
        segments = np.asarray(self.segments, dtype=np.float64)
        if segments.size % 4 or segments.ndim > 1 and segments.shape[-1] not in (2, 4):
            raise ValueError(f'segments must be (K, 2, 2) or (K, 4) numbers, got shape '
                             f'{segments.shape}')
        self.segments = as_segments(segments.reshape(-1, 2, 2))    # (and finite)
        self.support = np.asarray(self.support, dtype=np.float64).reshape(-1)
        if len(self.support) != len(self.segments):
            raise ValueError(f'support has {len(self.support)} values for '
                             f'{len(self.segments)} segments')
        if len(self.closed) != len(self.polylines):
            raise ValueError(f'closed has {len(self.closed)} flags for '
                             f'{len(self.polylines)} polylines')
        if self.trajectory is not None:
            trajectory = np.asarray(self.trajectory, dtype=np.float64)
            if trajectory.size % 4 or trajectory.ndim > 1 and trajectory.shape[-1] != 4:
                raise ValueError(f'trajectory must be (P, 4) numbers (t, x, y, yaw), got shape '
                                 f'{trajectory.shape}')
            self.trajectory = trajectory.reshape(-1, 4)
            if not np.isfinite(self.trajectory).all():
                raise ValueError('trajectory has NaN or inf')

    def __len__(self) -> int:
        """Return the number of segments."""
        return len(self.segments)

    @classmethod
    def empty(cls, frame_id: str = 'map', stamp: Optional[float] = None) -> 'MapValue':
        """Return a map without segments."""
        return cls(np.zeros((0, 2, 2)), np.zeros(0), [], [], frame_id, stamp)

    @classmethod
    def from_fit(cls, result, frame_id: str = 'map', stats: dict = None) -> 'MapValue':
        """Return the map of a batch ``FitResult``."""
        return cls(result.segments, result.support, list(result.polylines),
                   [bool(c) for c in result.closed], frame_id, None, dict(stats or {}))
