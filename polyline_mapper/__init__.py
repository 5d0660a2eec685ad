"""polyline_mapper: 2D polyline maps from laser scans by split-and-merge EM segment fitting."""

__version__ = '0.1.0'
