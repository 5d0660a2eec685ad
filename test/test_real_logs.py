"""The Intel lab log (Radish): convergence, accuracy and coverage of the batch fit."""

from conftest import radish_log
import numpy as np
from polyline_mapper.core import fit, map_metrics
from polyline_mapper.formats.carmen import read_carmen


def test_intel_lab_batch_fit():
    log = read_carmen(str(radish_log('intel-corrected.log.gz')))
    assert len(log.records) == 910 and log.skipped == 0
    assert abs(log.no_return - 81.83) < 1e-9
    pts = log.points()
    assert 150_000 < len(pts) < 170_000
    res = fit(pts)
    m = map_metrics(pts, res.segments)
    assert res.converged and res.iterations <= 30
    assert m['mean_distance'] <= 0.05
    assert m['coverage_0_10m'] >= 0.90
    # Compact: at least 50 points per segment end point.
    assert m['compression'] >= 50
    # Segments are real structure, not noise: each has at least min_support points.
    assert np.all(res.support >= 4)
