"""
MAP.json: the one writer and the one reader of the map file (schema_version 1).

``{"schema_version": 1, "frame_id": str, "segments": [[x1, y1, x2, y2], ...],
"polylines": [[[x, y], ...], ...], "closed": [bool, ...], "support": [float, ...],
"stats": {...}, "config": {...}, "grid": {...}}``; metres in ``frame_id``. Coordinates are
rounded to 0.1 mm and support to 0.01. The file never holds NaN or Infinity: a non-finite stat
(the mean distance of an empty map) is written as null. One top-level key per line, compact
values.

``grid`` (optional, written by ``replay`` and the node's ``~/save_map``) is the planner map
(``core.grid.GridMap``): ``{"resolution": m, "origin": [x, y], "width": W, "height": H,
"cells": [value, count, ...]}``, the cells (-1 unknown, 0 free, 100 occupied; row-major from
the lower-left cell, as nav_msgs/OccupancyGrid) run-length encoded; never with a map without a
segment (``usable_grid``). Readers that do not know it ignore it; ``read_map`` checks it and
returns it as ``MapFile.grid``.

``write_map`` writes a ``core.mapvalue.MapValue`` through ``formats.output`` (never over an
input, a device or a folder; all or nothing). ``read_map`` checks a file completely (size,
nesting, types, shapes, finite and sane coordinates, segments and support of equal length,
polylines whose edges are the segments) and raises ValueError with one line naming what is
wrong.
"""

import json
import math
import os
from typing import Iterable

import numpy as np
from scipy.spatial import cKDTree

from .output import OutputError, OutputSet, write_text_atomic
from .points import MAX_COORDINATE
from ..core.grid import check_resolution, decode_cells, DEFAULT_MAX_CELLS, encode_cells, GridMap
from ..core.mapvalue import MapValue

SCHEMA_VERSION = 1
COORD_DECIMALS = 4
"""Decimals of the coordinates a map file stores (metres: 0.1 mm)."""
MAX_MAP_BYTES = 64 * 2 ** 20
"""Largest map file read (64 MiB: about 700k segments, far beyond any building or campus)."""
MAX_GRID_RUNS = 3 * 2 ** 20
"""Largest run-length grid stored in a map file (about 30 MB of text; fr079 at 5 cm has 19k
runs, the Freiburg campus 2M). A larger grid is left out (``stats['grid_omitted']`` says so),
so the file stays readable."""
EDGE_TOLERANCE = 1e-3
"""How far (m, per coordinate) a polyline edge's ends may lie from its segment's ends. The
writer rounds both from the same numbers, so a map it wrote agrees exactly; 1 mm lets a file
rounded by another tool pass, far below what a drawing or a planner grid could show."""

__all__ = ['SCHEMA_VERSION', 'COORD_DECIMALS', 'MapFile', 'map_value_to_dict', 'map_to_dict',
           'dumps_map', 'stored_segments',
           'write_map', 'write_json_atomic', 'write_text_atomic', 'read_map', 'OutputError',
           'OutputSet', 'json_safe', 'map_value_from_dict', 'grid_to_dict', 'grid_from_dict',
           'usable_grid',
           'check_edges', 'EDGE_TOLERANCE']


def json_safe(value):
    """
    Return ``value`` with NaN / inf floats replaced by None and numpy scalars made plain.

    Recurses into dicts, lists and tuples (tuples become lists).
    """
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def map_value_to_dict(value: MapValue, config: dict = None, grid: GridMap = None) -> dict:
    """
    Return the JSON-ready dict of a map (the file's content, keys in the file's order).

    ``config``: the flat configuration the map was made with (optional); ``grid``: its planner
    map (optional, ``core.grid.GridMap``; not stored for a map without a segment, see
    ``usable_grid``). The map's ``stamp``
    goes into ``stats['stamp']`` (seconds, unless the stats have one). Support is left out
    when it is unknown (all NaN, e.g. a map read from a file without it).
    """
    support = np.asarray(value.support, dtype=np.float64)
    known = len(support) == 0 or not np.isnan(support).all()
    stats = dict(value.stats or {})
    if value.stamp is not None and 'stamp' not in stats:
        stats['stamp'] = round(float(value.stamp), 6)
    out = _content(value.segments, value.polylines, value.closed, support if known else None,
                   stats, config, value.frame_id)
    if value.trajectory is not None:            # [t, x, y, yaw] per scan: 1 us, 0.1 mm, 1e-6 rad
        t = value.trajectory
        out['trajectory'] = np.column_stack([np.round(t[:, 0], 6), np.round(t[:, 1:3], 4),
                                             _yaw_rounded(t[:, 3])]).tolist()
    if usable_grid(grid, value.segments) is not None:
        entry = grid_to_dict(grid)
        if len(entry['cells']) // 2 <= MAX_GRID_RUNS:
            out['grid'] = entry
        else:
            out['stats']['grid_omitted'] = (f"{len(entry['cells']) // 2} runs, more than "
                                            f'{MAX_GRID_RUNS}')
    return out


def usable_grid(grid, segments):
    """
    Return ``grid``, the planner map of a map with ``segments``, or None when it has no segment.

    A map without a segment has no wall: its grid is traced free space alone, which a planner
    that allows unknown cells crosses. The node publishes no grid before its first segment;
    neither is one stored with such a map, nor read from (or exported from) an older file
    that has one (an export audit: a map saved during the first updates, 0 segments and 42,393
    free cells, loaded in map_server as free space).
    """
    return grid if len(segments) else None


def _yaw_rounded(yaw: np.ndarray) -> np.ndarray:
    """
    Return yaw (rad) rounded to 1e-6 rad and kept in [-pi, pi).

    Rounding alone takes a yaw within 5e-7 of -pi to -3.141593, below -pi, and one near +pi
    to 3.141593 (>= pi): both are written as -3.141592, the same heading to 1.3e-6 rad.

    >>> _yaw_rounded(np.array([-np.pi, np.pi - 1e-9, 0.1234567])).tolist()
    [-3.141592, -3.141592, 0.123457]
    """
    out = np.round(np.asarray(yaw, dtype=np.float64), 6)
    out[(out < -np.pi) | (out >= np.pi)] = -3.141592
    return out


def grid_to_dict(grid: GridMap) -> dict:
    """Return the ``grid`` entry of a map JSON: resolution, origin, size, run-length cells."""
    return {'resolution': float(grid.resolution),
            'origin': [round(float(v), 6) for v in grid.origin],
            'width': grid.width, 'height': grid.height, 'cells': encode_cells(grid.data)}


def grid_from_dict(entry) -> GridMap:
    """Check a map JSON's ``grid`` entry; return its GridMap (ValueError names what is wrong)."""
    if not isinstance(entry, dict):
        raise ValueError('"grid" must be an object')
    for key in ('resolution', 'origin', 'width', 'height', 'cells'):
        if key not in entry:
            raise ValueError(f'"grid" has no "{key}"')
    try:
        res = check_resolution(entry['resolution'])
    except ValueError as exc:
        raise ValueError(f'"grid": {exc}') from None
    w, h = entry['width'], entry['height']
    if not (type(w) is int and type(h) is int and w >= 1 and h >= 1
            and w * h <= DEFAULT_MAX_CELLS):
        raise ValueError(f'"grid" width and height must be integers >= 1 with at most '
                         f'{DEFAULT_MAX_CELLS} cells, got {w!r} x {h!r}')
    origin = _coords([entry['origin']], 2, '"grid" origin')[0]
    return GridMap(decode_cells(entry['cells'], w, h), res, (float(origin[0]), float(origin[1])))


def map_to_dict(segments, polylines, closed=None, support=None, stats=None, config=None,
                frame_id: str = 'map') -> dict:
    """
    Build the JSON-ready dict of a map from its parts (floats rounded to 0.1 mm).

    The file content ``map_value_to_dict`` gives; ``support`` None leaves it out, ``closed``
    None marks every polyline open. Unlike a MapValue, the parts are not checked against each
    other (kept for producers that still hand over a support array of another length).
    """
    closed = [False] * len(polylines) if closed is None else closed
    return _content(segments, polylines, closed, support, stats, config, frame_id)


def stored_segments(segments) -> np.ndarray:
    """
    Return segments ((N, 2, 2), m) as a map file stores them: rounded to 0.1 mm.

    The planner grid saved beside them marks these too (``MappingSession.occupancy``), so
    that every cell the file's segments cross is occupied in the file's grid (a planner-map
    audit: composed from the unrounded ones, 18 crossed cells of the office map were not).
    """
    return np.round(np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2), COORD_DECIMALS)


def _content(segments, polylines, closed, support, stats, config, frame_id) -> dict:
    """Lay out the file: rounding (0.1 mm, support 0.01), key order, non-finite stats -> null."""
    out = {
        'schema_version': SCHEMA_VERSION,
        'frame_id': str(frame_id),
        'segments': stored_segments(segments).reshape(-1, 4).tolist(),
        'polylines': [np.round(np.asarray(p, dtype=np.float64), COORD_DECIMALS).tolist()
                      for p in polylines],
        'closed': [bool(c) for c in closed],
    }
    if support is not None:
        out['support'] = np.round(np.asarray(support, dtype=np.float64), 2).tolist()
    out['stats'] = json_safe(dict(stats or {}))
    if config is not None:
        out['config'] = json_safe(dict(config))
    return out


def dumps_map(data: dict) -> str:
    """JSON text with one top-level key per line and compact values (diff- and eye-friendly)."""
    rows = [f'  {json.dumps(k)}: {json.dumps(v, separators=(", ", ": "), allow_nan=False)}'
            for k, v in data.items()]
    return '{\n' + ',\n'.join(rows) + '\n}\n'


def write_map(path, value, config: dict = None, inputs: Iterable = (),
              grid: GridMap = None) -> dict:
    """
    Write a map (a MapValue, or a dict from ``map_value_to_dict``) to ``path``; return the dict.

    ``grid``: the planner map to store with a MapValue (optional).

    Through ``formats.output``: refuses (OutputError, a ValueError) an input, a device, a folder,
    a read-only file; keeps the mode of a file it replaces; all or nothing. A map ``read_map``
    would refuse (polylines that disagree with the segments, say) is not written: ValueError
    (one line; an API audit wrote a map with segments and no polylines, unreadable after).
    """
    if not isinstance(value, (MapValue, dict)):
        raise TypeError(f'write_map takes a MapValue or a map dict, got {type(value).__name__}'
                        + (' (MapValue.from_fit(result) makes one)'
                           if type(value).__name__ == 'FitResult' else ''))
    data = map_value_to_dict(value, config, grid) if isinstance(value, MapValue) else value
    map_value_from_dict(data)                       # the reader's checks, before any byte
    write_text_atomic(path, dumps_map(data), inputs)
    return data


def write_json_atomic(path, data: dict, inputs: Iterable = ()) -> None:
    """Write a map dict (from ``map_to_dict``) to ``path``; same rules as ``write_map``."""
    write_text_atomic(path, dumps_map(data), inputs)


class MapFile(dict):
    """
    A checked map file: the JSON object as a dict (as before) and the map as ``value``.

    Keys are the file's (``frame_id``, ``segments``, ``polylines``, ``closed``, ``stats``,
    ``config`` ...) plus ``segments_array`` ((K, 2, 2) float). ``value`` is the MapValue
    (support NaN when the file has none), ``config`` the configuration dict or None.
    """

    value: MapValue
    grid = None
    """The planner map stored in the file (``core.grid.GridMap``), or None."""

    @property
    def config(self):
        """Return the configuration the map was made with (a dict), or None."""
        return self.get('config')


def _reject_constant(name: str):
    raise ValueError(f'{name} is not valid JSON (non-finite numbers are not allowed)')


def _finite_float(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f'number {text[:20]} is out of range')
    return v


def _bounded_int(text: str) -> int:
    v = int(text)
    if abs(v) >= 2 ** 63:           # no count, size or coordinate of a map is that large
        raise ValueError(f'number {text[:20]} is out of range')
    return v


def _coords(obj, width: int, what: str) -> np.ndarray:
    """Check a list of ``width``-number lists; return it as an (N, width) float array."""
    if not isinstance(obj, list):
        raise ValueError(f'{what} must be a list, got {type(obj).__name__}')
    if not all(type(row) is list and len(row) == width for row in obj):
        raise ValueError(f'{what} must be a list of {width}-number lists')
    flat = [v for row in obj for v in row]
    if not {type(v) for v in flat} <= {int, float}:
        raise ValueError(f'{what} must hold numbers only')
    arr = np.array(flat, dtype=np.float64).reshape(-1, width)
    if not np.isfinite(arr).all() or (np.abs(arr) > MAX_COORDINATE).any():
        raise ValueError(f'{what} must be finite coordinates within +-{MAX_COORDINATE:g} m')
    return arr


def _parse(path: str) -> dict:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise ValueError(f'{path}: no such file') from None
    except OSError as exc:
        raise ValueError(f'{path}: cannot read ({exc.strerror or exc})') from None
    if not os.path.isfile(path):
        raise ValueError(f'{path}: not a regular file')
    if st.st_size > MAX_MAP_BYTES:
        raise ValueError(f'{path}: {st.st_size / 2 ** 20:.0f} MiB is too large for a map JSON '
                         f'(limit {MAX_MAP_BYTES // 2 ** 20} MiB)')
    try:
        with open(path, 'rb') as fh:
            raw = fh.read(MAX_MAP_BYTES + 1)
        if len(raw) > MAX_MAP_BYTES:
            raise ValueError(f'larger than {MAX_MAP_BYTES // 2 ** 20} MiB')
        return json.loads(raw.decode('utf-8'), parse_constant=_reject_constant,
                          parse_float=_finite_float, parse_int=_bounded_int)
    except RecursionError:
        raise ValueError(f'{path}: not a map JSON (nested too deeply)') from None
    except (OSError, ValueError) as exc:        # JSONDecodeError, UnicodeDecodeError
        msg = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
        raise ValueError(f'{path}: not a readable map JSON ({msg})') from None


def read_map(path) -> MapFile:
    """
    Read and check a map JSON file; return a MapFile (a dict with ``.value``, a MapValue).

    Raises ValueError with one line naming what is wrong: missing file, not JSON, too large or
    too deeply nested, NaN / Infinity, a missing key, a field of the wrong type or shape, a bad
    ``grid`` entry (resolution, size, origin, run-length cells that do not add up),
    non-finite or absurd coordinates (beyond +-1e8 m), segments and support of different
    lengths, polylines and closed flags of different lengths, polylines that disagree with the
    segments (``check_edges``).
    """
    path = os.fspath(path)
    data = _parse(path)
    try:
        value = map_value_from_dict(data)
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from None
    grid = None
    if data.get('grid') is not None:
        try:
            grid = grid_from_dict(data['grid'])
        except ValueError as exc:
            raise ValueError(f'{path}: {exc}') from None
    out = MapFile(data)
    out['segments_array'] = value.segments
    out.value = value
    out.grid = usable_grid(grid, value.segments)
    return out


def map_value_from_dict(data) -> MapValue:
    """
    Check the content of a map JSON (a dict, as parsed); return its MapValue.

    Raises ValueError (one line, without the file name) naming what is wrong.
    """
    if not isinstance(data, dict):
        raise ValueError('a map JSON must be an object')
    version = data.get('schema_version', SCHEMA_VERSION)
    if type(version) is not int or version != SCHEMA_VERSION:
        raise ValueError(f'schema_version {version!r} is not supported (this version reads '
                         f'{SCHEMA_VERSION})')
    for key in ('frame_id', 'segments', 'polylines'):
        if key not in data:
            raise ValueError(f'missing key "{key}"')
    if not isinstance(data['frame_id'], str):
        raise ValueError('"frame_id" must be a string')
    if not data['frame_id'].strip():        # the map's frame: published, broadcast on /tf
        raise ValueError('"frame_id" must name a frame, got an empty string')
    if any(ord(c) < 32 or ord(c) == 127 for c in data['frame_id']):
        # (export wrote it into the SVG, which then did not parse as XML)
        raise ValueError(f'"frame_id" must not hold control characters, got '
                         f'{data["frame_id"]!r}')
    segs = _coords(data['segments'], 4, '"segments"')
    polys = data['polylines']
    if not isinstance(polys, list):
        raise ValueError(f'"polylines" must be a list of vertex lists, got '
                         f'{type(polys).__name__}')
    polylines = []
    for i, p in enumerate(polys):
        verts = _coords(p, 2, f'"polylines"[{i}]')
        if len(verts) < 2:
            raise ValueError(f'"polylines"[{i}] must have at least 2 vertices')
        polylines.append(verts)
    closed = data.get('closed', [False] * len(polys))
    if not (isinstance(closed, list) and all(type(c) is bool for c in closed)):
        raise ValueError('"closed" must be a list of true / false')
    if len(closed) != len(polys):
        raise ValueError(f'"closed" has {len(closed)} flags for {len(polys)} polylines')
    if 'support' in data:
        sup = data['support']
        if not (isinstance(sup, list) and all(type(v) in (int, float) for v in sup)):
            raise ValueError('"support" must be a list of numbers')
        sup = np.array(sup, dtype=np.float64)
        if len(sup) != len(segs):
            raise ValueError(f'"support" has {len(sup)} values for {len(segs)} segments')
        if (sup < 0).any():             # point counts (the mapper refuses such a map to start)
            k = int(np.flatnonzero(sup < 0)[0])
            raise ValueError(f'"support" must be point counts >= 0, got {sup[k]:g} for '
                             f'segment {k}')
    else:
        sup = np.full(len(segs), np.nan)
    for key in ('stats', 'config'):
        if key in data and not isinstance(data[key], dict):
            raise ValueError(f'"{key}" must be an object')
    stats = dict(data.get('stats') or {})
    stamp = stats.get('stamp')
    stamp = float(stamp) if type(stamp) in (int, float) else None
    trajectory = None
    if 'trajectory' in data:
        rows = data['trajectory']
        if not (isinstance(rows, list) and all(
                isinstance(r, list) and len(r) == 4
                and all(type(v) in (int, float) for v in r) for r in rows)):
            raise ValueError('"trajectory" must be a list of [t, x, y, yaw]')
        trajectory = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
        if not np.isfinite(trajectory).all():
            raise ValueError('"trajectory" has non-finite numbers')
    check_edges(segs, polylines, closed)
    return MapValue(segs.reshape(-1, 2, 2), sup, polylines, list(closed), data['frame_id'],
                    stamp, stats, trajectory)


def _edges(polylines: list, closed: list) -> np.ndarray:
    """Return the edges of polylines as (E, 4) rows x1, y1, x2, y2, closing edges included."""
    rows = [np.hstack([v[:-1], v[1:]]) for v in polylines]
    rows += [np.hstack([v[-1], v[0]])[None] for v, shut in zip(polylines, closed) if shut]
    return np.concatenate(rows) if rows else np.zeros((0, 4))


EDGE_CANDIDATES = 32
"""``check_edges``: how many of the nearest edges a repeated segment may take the first free of."""


def _canonical(rows: np.ndarray) -> np.ndarray:
    """Return (N, 4) rows x1, y1, x2, y2, each with its lexicographically lower end first."""
    swap = (rows[:, 0] > rows[:, 2]) | ((rows[:, 0] == rows[:, 2]) & (rows[:, 1] > rows[:, 3]))
    return np.where(swap[:, None], rows[:, [2, 3, 0, 1]], rows)


def _row_order(rows: np.ndarray) -> np.ndarray:
    """Return the lexicographic order of (N, 4) rows."""
    return np.lexsort(rows.T[::-1])


def check_edges(segments, polylines: list, closed: list) -> None:
    """
    Check that the polylines' edges are the segments, one edge each, in any order or direction.

    The mapper chains its segments into the polylines (``core.polylines``): an open polyline of
    M vertices holds M - 1 of them, a closed one M (its last vertex joined to its first). A file
    whose two disagree would show one map in the GeoJSON and SVG exports (polylines) and another
    in the CSV and planner exports (segments). Ends may differ by ``EDGE_TOLERANCE`` per
    coordinate. Raises ValueError (one line) naming the first segment that is no edge.

    >>> check_edges([[1, 0, 0, 0], [1, 0, 1, 1]], [np.array([[0, 0], [1, 0], [1, 1]])], [False])
    >>> check_edges([[0, 0, 1, 0]], [np.array([[0, 0], [1, 0], [1, 1]])], [False])
    Traceback (most recent call last):
    ValueError: "polylines" disagree with "segments": 2 polyline edges for 1 segments ...
    """
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    polylines = [np.asarray(v, dtype=np.float64).reshape(-1, 2) for v in polylines]
    edges = _edges(polylines, closed)
    if len(edges) != len(segs):
        raise ValueError(f'"polylines" disagree with "segments": {len(edges)} polyline edges '
                         f'for {len(segs)} segments (each segment must be one polyline edge)')
    if not len(segs):
        return
    # Most files (every one this package writes) hold the edges themselves: the same rows,
    # sorted alike once each is put end-first, match one for one, repeated rows included.
    a, b = _canonical(segs), _canonical(edges)
    if np.abs(a[_row_order(a)] - b[_row_order(b)]).max() <= EDGE_TOLERANCE:
        return
    # Else each segment, in file order, takes the nearest edge still free within reach among
    # the ``EDGE_CANDIDATES`` nearest distinct ones. The k-d tree holds distinct rows only:
    # thousands of identical copies in one leaf made every query scan all of them.
    n = len(edges)
    both = np.vstack([edges, edges[:, [2, 3, 0, 1]]])     # either direction
    rows, inv = np.unique(both, axis=0, return_inverse=True)
    slots = np.argsort(inv.reshape(-1), kind='stable') % n     # each row's edges, grouped
    ends = np.cumsum(np.bincount(inv.reshape(-1), minlength=len(rows)))
    nxt = ends - np.bincount(inv.reshape(-1), minlength=len(rows))   # next slot to try
    _, cand = cKDTree(rows).query(segs, k=min(EDGE_CANDIDATES, len(rows)), p=np.inf,
                                  distance_upper_bound=EDGE_TOLERANCE)
    cand = cand.reshape(len(segs), -1)
    taken = np.zeros(n, dtype=bool)
    found = np.zeros(len(segs), dtype=bool)
    for k, near in enumerate(cand.tolist()):
        for r in near:
            if r >= len(rows):
                break
            while nxt[r] < ends[r] and taken[slots[nxt[r]]]:
                nxt[r] += 1
            if nxt[r] < ends[r]:
                taken[slots[nxt[r]]] = found[k] = True
                break
    if not found.all():
        k = int(np.argmin(found))
        x1, y1, x2, y2 = segs[k]
        raise ValueError(f'"polylines" disagree with "segments": segment {k} '
                         f'({x1:g}, {y1:g})-({x2:g}, {y2:g}) is no polyline edge (within '
                         f'{EDGE_TOLERANCE * 1000:g} mm)')


def config_dict(config) -> dict:
    """
    Return the flat ``config`` block of a map JSON for a fit or mapper configuration.

    An SMEMSFConfig gives its fields; an IncrementalConfig its SMEMSF fields and its own
    (without the nested ``smemsf``).
    """
    if hasattr(config, 'smemsf'):
        out = config.smemsf.to_dict()
        out.update({k: getattr(config, k) for k in config.__dataclass_fields__
                    if k != 'smemsf'})
        return out
    return config.to_dict()
