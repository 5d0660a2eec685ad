"""EMSF: E-step weights, weighted orthogonal regression, MAP trimming."""

from conftest import noisy_line
import numpy as np
from polyline_mapper.core.emsf import e_step, emsf_step, weighted_lines
from polyline_mapper.core.index import PointIndex


def test_weighted_lines_recover_orientation_of_noisy_line():
    rng = np.random.default_rng(0)
    for ang in np.deg2rad([0, 17, 45, 90, 133]):
        b = 4 * np.array([np.cos(ang), np.sin(ang)])
        pts = noisy_line([0, 0], b, 500, 0.01, rng)
        c, u, m = weighted_lines(pts, np.zeros(500, dtype=int), np.ones(500), 1)
        assert abs(abs(u[0] @ b / 4) - 1) < 1e-4          # parallel to the true line
        assert abs(u[0, 0] * c[0, 1] - u[0, 1] * c[0, 0]) < 0.005   # on the true line
        assert m[0] == 500


def test_e_step_weights_normalised_with_outlier_class():
    rng = np.random.default_rng(1)
    pts = np.concatenate([noisy_line([0, 0], [2, 0], 200, 0.01, rng),
                          noisy_line([0, 0.05], [2, 0.05], 200, 0.01, rng),
                          [[1.0, 5.0]]])                    # far away: no segment reaches it
    segs = np.array([[[0, 0], [2, 0]], [[0, 0.05], [2, 0.05]]], dtype=float)
    est = e_step(PointIndex(pts), segs, sigma=0.02, kappa=3.0)
    total = np.bincount(est.pairs.pt, weights=est.weight, minlength=len(pts))
    assert np.all(total <= 1 + 1e-12)
    assert total[-1] == 0 and est.support[-1] == -1
    # Points on a line mostly belong to that line.
    assert np.mean(est.support[:200] == 0) > 0.85
    assert np.mean(est.support[200:400] == 1) > 0.85


def test_emsf_step_trims_to_support_and_drops_empty_segments():
    rng = np.random.default_rng(2)
    pts = noisy_line([1, 1], [3, 1], 400, 0.005, rng)
    segs = np.array([[[0, 1.01], [5, 1.01]],                 # too long, slightly off
                     [[0, 9], [1, 9]]], dtype=float)          # nothing near it
    new, sup, _ = emsf_step(PointIndex(pts), segs, 0.02, 3.0, min_support=4)
    assert len(new) == 1 and sup[0] == 400
    ends = np.sort(new[0, :, 0])
    assert abs(ends[0] - pts[:, 0].min()) < 0.01 and abs(ends[1] - pts[:, 0].max()) < 0.01
    assert np.allclose(new[0, :, 1], 1.0, atol=0.003)


def test_fit_keeps_a_sparsely_seen_face_at_low_noise():
    # A 6 m x 4 m room seen densely, and a 0.8 m box face passed at a distance: 22 points,
    # 3.6 cm apart on average, wider than the noise band (0.5 cm noise: 2r is about 2.5 cm).
    # Its points are a clean line no other segment explains, so the map must keep it.
    from polyline_mapper.core import fit
    rng = np.random.default_rng(7)
    corners = [(0, 0), (6, 0), (6, 4), (0, 4)]
    room = [noisy_line(corners[i], corners[(i + 1) % 4], 1500, 0.005, rng) for i in range(4)]
    face_a, face_b = np.array([2.0, 2.5]), np.array([2.8, 2.5])
    face = noisy_line(face_a, face_b, 22, 0.005, rng)
    res = fit(np.concatenate(room + [face]))
    along = [min(s[:, 0].max(), face_b[0]) - max(s[:, 0].min(), face_a[0])
             for s in res.segments if np.abs(s[:, 1] - face_a[1]).max() < 0.02]
    assert along and max(along) >= 0.8 * 0.8      # one segment along >= 80 % of the face
