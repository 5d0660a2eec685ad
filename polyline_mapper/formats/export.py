"""
Map JSON -> GeoJSON, SVG and CSV, for GIS tools, drawings and spreadsheets.

- GeoJSON: a FeatureCollection with one LineString per polyline (a closed polyline repeats its
  first vertex at the end). Coordinates are the map's own metres in ``frame_id`` (not WGS 84
  longitude / latitude): load them as a local, projected layer. Properties: polyline index,
  closed flag, vertex count, length (m); the collection carries ``frame_id`` and ``units``.
- SVG: the polylines drawn with y up (map y grows towards the top of the picture), 1 m = ``scale``
  pixels, with a 1-2-5 scale bar. Closed polylines are ``polygon`` elements without fill.
- CSV: one row per segment, ``x1,y1,x2,y2,support`` (support empty when the map has none).
- YAML + PGM: the map_server pair a planner loads (``nav2_map_server``, ``map_server``):
  ``NAME.pgm`` (binary P5, 8 bit, first row at the top, i.e. the highest y) beside
  ``NAME.yaml`` (``image`` relative to the YAML; a YAML that is a symlink gets its pair beside
  the link's target, ``map_yaml_image``; ``mode: trinary``, ``resolution``,
  ``origin: [x, y, 0.0]`` of the lower-left pixel, ``negate: 0``, ``occupied_thresh: 0.65``,
  ``free_thresh: 0.196``). Pixels follow map_saver's trinary convention: occupied 0 (black),
  free 254, unknown 205. map_server reads a pixel as occupancy p = (255 - value) / 255:
  p > 0.65 is occupied, p < free_thresh free, else unknown. Unknown 205 gives p = 0.19608, so
  free_thresh must stay at or below 0.196 (with 0.25, the value map_saver writes, unknown
  cells would load as free). The grid is the one stored in the map (``replay``, the node's
  ``~/save_map``); a map without one gives its segments' cells occupied and all else unknown,
  at ``GRID_RESOLUTION``; a map without a segment gives one unknown cell (its traced free space
  alone is no map a planner can use).
- The trajectory (``--trajectory``; a map from ``replay`` holds one: one row per scan used, the
  base frame's pose in the map frame at the scan's header stamp): CSV ``t,x,y,yaw`` (seconds,
  metres, radians), or the TUM RGB-D format (``.tum``: ``timestamp tx ty tz qx qy qz qw`` per
  line, space separated, tz 0 and the yaw as a quaternion about z), which trajectory tools
  (``evo``, the TUM benchmark scripts) read.
"""

import io
import json
import os
import re
from xml.sax.saxutils import escape

import numpy as np

from .mapjson import grid_from_dict, map_value_from_dict, MapFile, usable_grid
from .output import OutputSet, write_text_atomic
from ..core.grid import check_resolution, FREE, GridMap, OCCUPIED, rasterise

FORMATS = ('geojson', 'svg', 'csv', 'yaml')
TRAJECTORY_FORMATS = ('csv', 'tum')
GRID_RESOLUTION = 0.05
"""Cell size (m) of the grid exported from a map that stores none."""
PGM_OCCUPIED, PGM_FREE, PGM_UNKNOWN = 0, 254, 205
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.196


def _polylines(data: dict) -> list:
    return [np.asarray(p, dtype=float).reshape(-1, 2) for p in data.get('polylines', [])]


def _closed(data: dict, n: int) -> list:
    closed = list(data.get('closed') or [])
    return [bool(c) for c in closed] + [False] * (n - len(closed))


def to_geojson(data: dict) -> dict:
    """Return the GeoJSON FeatureCollection (a dict) of a map read by ``read_map``."""
    polys = _polylines(data)
    features = []
    for i, (p, closed) in enumerate(zip(polys, _closed(data, len(polys)))):
        verts = np.vstack([p, p[:1]]) if closed and len(p) > 2 else p
        length = float(np.linalg.norm(np.diff(verts, axis=0), axis=1).sum())
        features.append({'type': 'Feature', 'id': i,
                         'geometry': {'type': 'LineString', 'coordinates': verts.tolist()},
                         'properties': {'polyline': i, 'closed': closed, 'vertices': len(p),
                                        'length_m': round(length, 4)}})
    return {'type': 'FeatureCollection', 'frame_id': data.get('frame_id', 'map'),
            'units': 'm', 'features': features}


def _scale_bar_length(width_m: float) -> float:
    target = max(width_m / 5.0, 1e-3)
    exp = 10.0 ** np.floor(np.log10(target))
    return max(m * exp for m in (1, 2, 5) if m * exp <= target)


_NOT_XML = re.compile('[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]')
"""Characters XML 1.0 does not allow in a document (its ``Char`` production)."""


def _xml_text(text: str) -> str:
    """Return ``text`` escaped for XML, each character XML cannot hold replaced by U+FFFD."""
    return escape(_NOT_XML.sub('\ufffd', text))


def to_svg(data: dict, scale: float = 50.0, margin: float = 0.5) -> str:
    """
    Return an SVG drawing of a map's polylines with y up and a scale bar.

    ``scale``: pixels per metre; ``margin``: metres of blank border.
    """
    polys = _polylines(data)
    closed = _closed(data, len(polys))
    verts = np.concatenate(polys) if polys else np.zeros((0, 2))
    segs = np.asarray(data.get('segments', []), dtype=float).reshape(-1, 4)
    allv = verts if len(verts) else segs.reshape(-1, 2)
    lo = allv.min(axis=0) if len(allv) else np.zeros(2)
    hi = allv.max(axis=0) if len(allv) else np.ones(2)
    span = np.maximum(hi - lo, 1.0)
    bar_room = 1.0                                   # metres below the map for the scale bar
    width = span[0] + 2 * margin
    height = span[1] + 2 * margin + bar_room

    def xy(p):                                       # map metres -> SVG user units (pixels)
        return (p[:, 0] - lo[0] + margin) * scale, (hi[1] - p[:, 1] + margin) * scale

    out = io.StringIO()
    out.write(f'<?xml version="1.0" encoding="UTF-8"?>\n'
              f'<svg xmlns="http://www.w3.org/2000/svg" width="{width * scale:.1f}" '
              f'height="{height * scale:.1f}" viewBox="0 0 {width * scale:.1f} '
              f'{height * scale:.1f}">\n'
              f'<title>{_xml_text(str(data.get("frame_id", "map")))}: {len(polys)} polylines, '
              f'{len(segs)} segments (1 m = {scale:g} px, y up)</title>\n'
              '<rect width="100%" height="100%" fill="white"/>\n'
              '<g fill="none" stroke="#1f77b4" stroke-width="2" stroke-linejoin="round" '
              'stroke-linecap="round">\n')
    for p, c in zip(polys, closed):
        x, y = xy(p)
        pts = ' '.join(f'{a:.1f},{b:.1f}' for a, b in zip(x, y))
        out.write(f'<{"polygon" if c else "polyline"} points="{pts}"/>\n')
    out.write('</g>\n')
    length = _scale_bar_length(span[0])
    x0 = margin * scale
    y0 = (span[1] + 2 * margin + 0.5 * bar_room) * scale
    label = f'{length:g} m' if length >= 1 else f'{length * 100:g} cm'
    out.write(f'<g id="scale-bar"><line x1="{x0:.1f}" y1="{y0:.1f}" '
              f'x2="{x0 + length * scale:.1f}" y2="{y0:.1f}" stroke="black" stroke-width="4"/>'
              f'<text x="{x0 + 0.5 * length * scale:.1f}" y="{y0 - 6:.1f}" '
              f'text-anchor="middle" font-family="sans-serif" font-size="14">{label}</text>'
              '</g>\n</svg>\n')
    return out.getvalue()


def to_csv(data: dict) -> str:
    """Return the segments of a map as CSV text: header ``x1,y1,x2,y2,support``, one row each."""
    segs = np.asarray(data.get('segments', []), dtype=float).reshape(-1, 4)
    support = data.get('support')
    rows = ['x1,y1,x2,y2,support']
    for i, s in enumerate(segs):
        sup = '' if support is None or i >= len(support) else f'{float(support[i]):g}'
        rows.append(','.join(f'{v:.4f}' for v in s) + f',{sup}')
    return '\n'.join(rows) + '\n'


def trajectory_csv(trajectory: np.ndarray) -> str:
    """Return a trajectory (T, 4) as CSV text: header ``t,x,y,yaw``, one row per pose."""
    rows = ['t,x,y,yaw']
    rows += [f'{t:.6f},{x:.4f},{y:.4f},{yaw:.6f}' for t, x, y, yaw in trajectory + 0.0]
    return '\n'.join(rows) + '\n'


def trajectory_tum(trajectory: np.ndarray) -> str:
    """
    Return a trajectory (T, 4) in the TUM format: ``timestamp tx ty tz qx qy qz qw`` lines.

    >>> print(trajectory_tum(np.array([[1.5, 2.0, -1.0, np.pi / 2]])), end='')
    1.500000 2.0000 -1.0000 0.0000 0.000000 0.000000 0.707107 0.707107
    """
    t = np.asarray(trajectory, dtype=np.float64).reshape(-1, 4) + 0.0     # no '-0.0000'
    half = t[:, 3] / 2.0
    return ''.join(f'{r[0]:.6f} {r[1]:.4f} {r[2]:.4f} 0.0000 0.000000 0.000000 {qz:.6f} '
                   f'{qw:.6f}\n' for r, qz, qw in zip(t, np.sin(half) + 0.0, np.cos(half)))


def export_trajectory(data: dict, path: str, fmt: str = None, inputs=()) -> str:
    """
    Write the trajectory a map holds to ``path`` as CSV or TUM; return the format.

    The format comes from ``fmt`` or the suffix (``.csv``; ``.tum`` or ``.txt`` for TUM).
    Raises ValueError when the map holds no trajectory, on another format, or on a refused
    output (``formats.output``: never over an input, a device or a folder).
    """
    fmt = (fmt or os.path.splitext(path)[1].lstrip('.')).lower()
    fmt = 'tum' if fmt == 'txt' else fmt
    if fmt not in TRAJECTORY_FORMATS:
        raise ValueError(f'{path}: unknown trajectory format {fmt!r} (expected .csv, .tum or '
                         '.txt, or --format csv|tum)')
    traj = map_value_from_dict(data).trajectory
    if traj is None or not len(traj):
        raise ValueError('the map holds no trajectory (replay writes one: one pose per scan '
                         'used)' + ('' if traj is None else '; its "trajectory" is empty'))
    write_text_atomic(path, (trajectory_csv if fmt == 'csv' else trajectory_tum)(traj), inputs)
    return fmt


def planner_grid(data: dict, resolution: float = None) -> GridMap:
    """
    Return the planner map of a map dict: its stored ``grid``, else its segments rasterised.

    ``resolution`` (m): the cell size of the rasterised segments (default ``GRID_RESOLUTION``);
    a map that stores its grid has its own (ValueError when another is asked for). A map
    without a segment gives all cells unknown, whatever it stores (``usable_grid``).
    """
    segs = np.asarray(data.get('segments', []), dtype=float).reshape(-1, 2, 2)
    if usable_grid(data.get('grid'), segs) is not None:
        grid = grid_from_dict(data['grid'])
        if resolution is not None and resolution != grid.resolution:
            raise ValueError(f'the map stores its planner grid at {grid.resolution:g} m; a '
                             'resolution applies to a map without one (as fit writes)')
        return grid
    try:                                # a cell size out of range is said as such
        res = check_resolution(GRID_RESOLUTION if resolution is None else float(resolution))
    except ValueError as exc:
        raise ValueError(f'{exc} (export --resolution M)') from None
    try:
        return rasterise(segs, res)
    except ValueError as exc:
        raise ValueError(f'the map is too large for a grid export: {exc} (export '
                         '--resolution M)') from None


def to_pgm(grid: GridMap) -> bytes:
    """Return the grid as a binary PGM (P5) in map_saver's trinary shades, top row first."""
    shades = np.full(grid.data.shape, PGM_UNKNOWN, dtype=np.uint8)
    shades[grid.data == FREE] = PGM_FREE
    shades[grid.data == OCCUPIED] = PGM_OCCUPIED
    header = f'P5\n# polyline_mapper planner map, {grid.resolution:g} m/pixel\n' \
             f'{grid.width} {grid.height}\n255\n'
    return header.encode('ascii') + np.flipud(shades).tobytes()


def to_map_yaml(grid: GridMap, image: str) -> str:
    """
    Return the map_server YAML of ``grid`` whose image file is ``image`` (relative name).

    The name is a double-quoted YAML string, its characters as they are (UTF-8; only control
    characters escaped): a character beyond U+FFFF escaped as JSON does, as a surrogate pair,
    is refused by yaml-cpp (nav2_map_server) as invalid Unicode.
    """
    return (f'image: {json.dumps(image, ensure_ascii=False)}\n'
            'mode: trinary\n'
            f'resolution: {grid.resolution!r}\n'
            f'origin: [{float(grid.origin[0])!r}, {float(grid.origin[1])!r}, 0.0]\n'
            'negate: 0\n'
            f'occupied_thresh: {OCCUPIED_THRESH}\n'
            f'free_thresh: {FREE_THRESH}\n')


def map_yaml_image(path: str) -> tuple:
    """
    Return ``(PGM file, image)``: where the image of the map_server YAML ``path`` goes, its name.

    ``NAME.pgm`` beside ``NAME.yaml``, ``image`` (the YAML's entry) its bare name. A YAML that
    is a symlink is written through the link (``formats.output``), so the PGM goes beside the
    link's target, named after it: loading the target finds it. map_server takes a relative
    ``image`` relative to the YAML path it was given, unresolved: when the link lies in another
    folder than its target, ``image`` is the PGM's absolute path, so that loading the link
    finds it too.
    """
    if not os.path.islink(path):
        pgm = os.path.splitext(path)[0] + '.pgm'
        return pgm, os.path.basename(pgm)
    target = os.path.realpath(path)
    pgm = os.path.splitext(target)[0] + '.pgm'
    same = os.path.realpath(os.path.dirname(os.path.abspath(path))) == os.path.dirname(target)
    return pgm, (os.path.basename(pgm) if same else pgm)


def export_map(data: dict, path: str, fmt: str = None, inputs=(),
               resolution: float = None) -> str:
    """
    Write a map to ``path`` as GeoJSON, SVG, CSV or a map_server YAML + PGM pair.

    The format comes from ``fmt`` or the file suffix; the PGM goes beside the YAML, same name
    (beside a symlink's target, ``map_yaml_image``).

    ``data``: a map checked by ``read_map`` (finite coordinates, polylines that agree with the
    segments), or a map dict, checked here the same way. Written through ``formats.output``
    (never over one of ``inputs``, a device or a folder; a failure leaves nothing behind).
    ``resolution``: the YAML + PGM pair's cell size (m) for a map without a stored grid
    (``planner_grid``). Returns the format. Raises ValueError on an unknown format, a map that
    fails the checks or a refused output.
    """
    fmt = (fmt or os.path.splitext(path)[1].lstrip('.')).lower()
    fmt = 'yaml' if fmt == 'yml' else fmt
    if fmt in ('yaml', 'pgm') and '.pgm' in (os.path.splitext(path)[1].lower(),
                                             os.path.splitext(os.path.realpath(path))[1].lower()):
        raise ValueError(f'{path}: name the map_server YAML (OUT.yaml); its image OUT.pgm is '
                         'written beside it')
    if fmt not in FORMATS:
        raise ValueError(f'{path}: unknown export format {fmt!r} (expected .geojson, .svg, '
                         '.csv or .yaml, or --format)')
    # finite, sane coordinates (no NaN / Infinity written); polylines whose edges are the
    # segments (GeoJSON and SVG draw the one, CSV and the grid the other: the same map).
    # A MapFile is what read_map returned, checked so already.
    if not isinstance(data, MapFile):
        map_value_from_dict(data)
    if fmt == 'yaml':
        pgm, image = map_yaml_image(path)
        try:
            image.encode('utf-8')
        except UnicodeEncodeError:
            raise ValueError(f'{os.fsencode(path)!r}: the image name is not valid UTF-8, so '
                             "map_server's YAML cannot name it: choose another file name") \
                from None
        with OutputSet(inputs) as out:
            out.add(path)
            out.add(pgm)
            grid = planner_grid(data, resolution)
            out.put(pgm, to_pgm(grid))
            out.put(path, to_map_yaml(grid, image))
        return fmt
    if resolution is not None:
        raise ValueError('a resolution applies to the map_server YAML + PGM export only')
    text = {'geojson': lambda d: json.dumps(to_geojson(d), separators=(',', ':'),
                                            allow_nan=False) + '\n',
            'svg': to_svg, 'csv': to_csv}[fmt](data)
    write_text_atomic(path, text, inputs)
    return fmt
