"""Probabilistic Hough transform (cv2.HoughLinesP) on the points rasterised to a grid."""

import numpy as np


def rasterise(points: np.ndarray, cell: float = 0.05, min_hits: int = 1) -> tuple:
    """
    Occupancy image of the points.

    Returns
    -------
    image : (H, W) uint8, 255 where a cell holds at least ``min_hits`` points; row = y, col = x.
    origin : (2,) metres, the lower-left corner of pixel (0, 0).

    """
    pts = np.asarray(points, dtype=np.float64)
    origin = pts.min(axis=0) - cell
    ij = np.floor((pts - origin) / cell).astype(np.int64)
    w, h = ij.max(axis=0) + 2
    counts = np.bincount(ij[:, 1] * w + ij[:, 0], minlength=w * h).reshape(h, w)
    return np.where(counts >= min_hits, 255, 0).astype(np.uint8), origin


def hough_segments(points, cell: float = 0.05, threshold: int = 20, min_length: float = 0.3,
                   max_gap: float = 0.2, theta_deg: float = 0.5, min_hits: int = 1) -> np.ndarray:
    """
    Segments from cv2.HoughLinesP on the rasterised points.

    Parameters
    ----------
    points
        (N, 2) metres.
    cell
        Raster cell (m).
    threshold
        Accumulator votes (cells) a line needs.
    min_length, max_gap
        Cv2's minLineLength and maxLineGap, here in metres.
    theta_deg
        Angular resolution (deg); rho resolution is one cell.
    min_hits
        Points a cell needs to be occupied.

    Returns
    -------
    (K, 2, 2) segments in metres (pixel centres).

    """
    import cv2
    img, origin = rasterise(points, cell, min_hits)
    lines = cv2.HoughLinesP(img, 1, np.deg2rad(theta_deg), int(threshold),
                            minLineLength=min_length / cell, maxLineGap=max_gap / cell)
    if lines is None:
        return np.zeros((0, 2, 2))
    px = lines.reshape(-1, 2, 2).astype(np.float64)
    return origin + (px + 0.5) * cell
