"""
Baseline line-map methods for the comparison benchmark (benchmarks/compare.py).

The numeric parts are numpy/scipy only and unit-tested (test/test_baselines.py): plain EM with a
fixed number of lines, EM with the number of lines chosen by BIC, per-scan split-and-merge with
merging across scans, gap splitting, and the wall precision / recall metric. The library calls
(cv2.approxPolyDP, skimage.measure.ransac, cv2.HoughLinesP) are thin and imported lazily, so
this package imports without OpenCV or scikit-image.
"""

from .em import bic_score, em_bic, em_lines, EMResult, log_likelihood
from .hough import hough_segments, rasterise
from .lines import fit_line, line_segments, split_at_gaps
from .ransac import sequential_ransac
from .scan_split import (approx_poly, break_at_jumps, iterative_end_point_fit, scan_segments,
                         SegmentMerger)
from .walls import split_at_junctions, wall_scores
from .worlds import cluttered_room

__all__ = ['approx_poly', 'bic_score', 'break_at_jumps', 'cluttered_room', 'em_bic', 'em_lines',
           'EMResult', 'fit_line', 'hough_segments', 'iterative_end_point_fit', 'line_segments',
           'log_likelihood', 'rasterise', 'scan_segments', 'SegmentMerger', 'sequential_ransac',
           'split_at_gaps', 'split_at_junctions', 'wall_scores']
