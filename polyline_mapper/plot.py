"""PNG rendering of points and a fitted map (matplotlib, Agg backend, no display needed)."""

import numpy as np


def plot_map(path, points: np.ndarray, segments: np.ndarray, polylines=None,
             title: str = '', max_points: int = 200_000, truth=None, dpi: int = 150) -> None:
    """
    Write a PNG of the points (grey), the map (one colour per polyline) and end points.

    Parameters
    ----------
    path : str or binary file object
        Where the PNG goes (a file name, or e.g. ``io.BytesIO`` to stage it in memory).
    points : (N, 2) array
        Metres; at most ``max_points`` are drawn (evenly subsampled).
    segments : (K, 2, 2) array
        Metres, drawn when ``polylines`` is None.
    polylines : list, optional
        (M, 2) vertex arrays.
    title : str
        Figure title.
    max_points : int
        Most points drawn.
    truth : (W, 2, 2) array, optional
        Ground-truth walls, drawn thin and dashed underneath.
    dpi : int
        Resolution.

    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    pts = np.asarray(points)
    if len(pts) > max_points:
        pts = pts[:: int(np.ceil(len(pts) / max_points))]
    if len(pts):
        lo, hi = pts.min(axis=0), pts.max(axis=0)
    elif len(segments):
        lo, hi = segments.reshape(-1, 2).min(axis=0), segments.reshape(-1, 2).max(axis=0)
    else:
        lo, hi = np.zeros(2), np.ones(2)
    span = np.maximum(hi - lo, 1.0)
    width = 12.0
    height = float(np.clip(width * span[1] / span[0], 4.0, 16.0))
    fig, ax = plt.subplots(figsize=(width, height))
    try:
        _draw(ax, pts, segments, polylines, truth, (lo, hi, span), title)
        fig.tight_layout()
        fig.savefig(path, dpi=dpi, format='png')
    finally:
        plt.close(fig)


def plot_free_space(path, points: np.ndarray, origins: np.ndarray, segments: np.ndarray,
                    contradicted: np.ndarray, title: str = '', max_beams: int = 10_000,
                    dpi: int = 120) -> None:
    """
    Write a PNG of laser beams (thin, light) under a map whose contradicted segments are red.

    Parameters
    ----------
    path : str or binary file object
        Where the PNG goes.
    points, origins : (N, 2) arrays
        Beam endpoints and laser positions, metres; at most ``max_beams`` beams are drawn
        (evenly subsampled).
    segments : (K, 2, 2) array
        The map, metres.
    contradicted : (K,) bool array
        Segments drawn in red (``core.freespace.judge``); the legend gives their share of map
        length.
    title : str
        Figure title.
    max_beams : int
        Most beams drawn.
    dpi : int
        Resolution.

    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    pts, org = np.asarray(points), np.asarray(origins)
    segs = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    bad = np.asarray(contradicted, dtype=bool)
    step = max(1, int(np.ceil(len(pts) / max(max_beams, 1))))
    beams = np.stack([org[::step], pts[::step]], axis=1)
    ext = np.concatenate([pts.reshape(-1, 2), segs.reshape(-1, 2)])
    lo, hi = (ext.min(axis=0), ext.max(axis=0)) if len(ext) else (np.zeros(2), np.ones(2))
    span = np.maximum(hi - lo, 1.0)
    width = 12.0
    height = float(np.clip(width * span[1] / span[0], 4.0, 16.0))
    fig, ax = plt.subplots(figsize=(width, height))
    try:
        if len(beams):
            ax.add_collection(LineCollection(beams, colors='tab:blue', linewidths=0.15,
                                             antialiaseds=False, alpha=0.07, zorder=1,
                                             rasterized=True))     # few grey levels: small PNG
        ax.add_collection(LineCollection(segs[~bad], colors='k', linewidths=1.0, zorder=3))
        ax.add_collection(LineCollection(segs[bad], colors='red', linewidths=2.2, zorder=4))
        length = np.hypot(*(segs[:, 1] - segs[:, 0]).T)
        share = length[bad].sum() / length.sum() if length.sum() > 0 else 0.0
        handles = [Line2D([], [], color='tab:blue', lw=1, alpha=0.5,
                          label=f'beams ({len(beams)} of {len(pts)} drawn)'),
                   Line2D([], [], color='k', lw=1, label=f'map ({len(segs)} segments)'),
                   Line2D([], [], color='red', lw=2.2,
                          label=f'contradicted: {share * 100:.1f}% of map length '
                                f'({int(bad.sum())} segments)')]
        # below the map, in a strip of its own: over the map it hid walls
        fig.legend(handles=handles, loc='lower center', ncol=3, fontsize=9, frameon=False)
        _frame(ax, lo, hi, span, title)
        fig.tight_layout(rect=(0.0, 0.3 / height, 1.0, 1.0))
        fig.savefig(path, dpi=dpi, format='png')
    finally:
        plt.close(fig)


TAB10_GREY = 7
"""Index of tab10's grey, left out of ``polyline_colours``."""


def polyline_colours(n: int) -> list:
    """
    Return ``n`` RGBA colours for polylines, cycling through tab10 without its grey.

    The points are drawn grey (0.55), and tab10's grey (0.50) would hide every tenth polyline
    on them.
    """
    import matplotlib.pyplot as plt
    cmap = plt.get_cmap('tab10')
    palette = [cmap(i) for i in range(10) if i != TAB10_GREY]
    return [palette[i % len(palette)] for i in range(n)]


def _draw(ax, pts, segments, polylines, truth, box, title) -> None:
    """Draw truth, points, map, scale bar and labels on ``ax``; ``box``: (lo, hi, span)."""
    from matplotlib.collections import LineCollection
    lo, hi, span = box
    if truth is not None and len(truth):
        ax.add_collection(LineCollection(truth, colors='0.6', linewidths=0.6, linestyles='--',
                                         zorder=1))
    if len(pts):
        ax.scatter(pts[:, 0], pts[:, 1], s=0.3, c='0.55', linewidths=0, zorder=2,
                   rasterized=True)
    if polylines:
        lines = [np.asarray(p) for p in polylines]
        ax.add_collection(LineCollection(lines, colors=polyline_colours(len(lines)),
                                         linewidths=1.6, zorder=3))
        verts = np.concatenate(lines)
        ax.scatter(verts[:, 0], verts[:, 1], s=6, c='k', zorder=4)
    elif len(segments):
        ax.add_collection(LineCollection(segments, colors='tab:red', linewidths=1.6, zorder=3))
        ax.scatter(segments[:, :, 0].ravel(), segments[:, :, 1].ravel(), s=6, c='k', zorder=4)
    _frame(ax, lo, hi, span, title)
    ax.grid(True, lw=0.3, alpha=0.5)


def _frame(ax, lo, hi, span, title) -> None:
    """Set equal axes over the box (3 % margin), metre labels, a scale bar and the title."""
    lo = 0.5 * (lo + hi - span)     # a box narrower than ``span`` (1 m) is centred in it
    hi = lo + span
    pad = 0.03 * span
    ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
    ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])
    ax.set_aspect('equal')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    _scale_bar(ax, lo - pad, span)
    if title:
        ax.set_title(drawable(title), fontsize=10)


def drawable(text: str) -> str:
    """
    Return ``text`` as a font can draw it.

    A file name's undecodable bytes (kept by Python as lone surrogates, which matplotlib's text
    layout refuses with a TypeError) become U+FFFD.
    """
    return str(text).encode('utf-8', 'surrogateescape').decode('utf-8', 'replace')


def _scale_bar(ax, corner, span) -> None:
    """Draw a 1-2-5 scale bar of about a fifth of the width in the lower-left corner."""
    target = span[0] / 5.0
    exp = 10.0 ** np.floor(np.log10(target))
    length = max(m * exp for m in (1, 2, 5) if m * exp <= target)
    x0 = corner[0] + 0.04 * span[0]
    y0 = corner[1] + 0.04 * span[1]
    ax.plot([x0, x0 + length], [y0, y0], color='k', lw=3, zorder=5)
    label = f'{length:g} m' if length >= 1 else f'{length * 100:g} cm'
    ax.text(x0 + length / 2, y0 + 0.015 * span[1], label, ha='center', va='bottom', fontsize=9,
            zorder=5)
