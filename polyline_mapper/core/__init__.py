"""
ROS-free numeric core of polyline_mapper (numpy and scipy only).

The public entry points are re-exported here: ``fit`` and ``SMEMSFConfig`` for batch fitting,
``map_metrics`` for quality numbers, ``assemble_polylines`` for chaining segments.
"""

from .metrics import map_metrics
from .polylines import assemble_polylines
from .smemsf import fit, FitResult, SMEMSFConfig

__all__ = ['assemble_polylines', 'fit', 'FitResult', 'map_metrics', 'SMEMSFConfig']
