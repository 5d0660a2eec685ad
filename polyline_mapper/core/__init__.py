"""
ROS-free numeric core of polyline_mapper (numpy and scipy only).

The public entry points are re-exported here: ``fit`` and ``SMEMSFConfig`` for batch fitting
(a ``FitResult``), ``IncrementalMapper`` and ``IncrementalConfig`` for mapping scan by scan (an
``UpdateInfo`` per update, a ``MapGeometry`` from ``polylines()``), ``map_metrics`` for quality
numbers, ``assemble_polylines`` for chaining segments (a ``Chains``).

Modules: ``geometry`` (element-wise segment geometry), ``index`` (spatial indexes), ``emsf``,
``split``, ``merge``, ``seed``, ``noise`` (the method's steps and scales), ``smemsf`` (the batch
loop), ``incremental`` (the online mapper), ``cleanup`` (what takes segments out of its map),
``polylines`` (chaining and the published map), ``metrics``, ``mapvalue`` (the map as one value).
"""

from .incremental import IncrementalConfig, IncrementalMapper, UpdateInfo
from .metrics import map_metrics
from .polylines import assemble_polylines, Chains, MapGeometry
from .smemsf import fit, FitResult, SMEMSFConfig

__all__ = ['assemble_polylines', 'Chains', 'fit', 'FitResult', 'IncrementalConfig',
           'IncrementalMapper', 'map_metrics', 'MapGeometry', 'SMEMSFConfig', 'UpdateInfo']
