"""
The map JSON schema shared by the CLI, the replay tools and the node's save_map service.

``{"frame_id": str, "segments": [[x1, y1, x2, y2], ...], "polylines": [[[x, y], ...], ...],
"closed": [bool, ...], "support": [float, ...], "stats": {...}, "config": {...}}``; metres.
Files are written to a temporary name and renamed, so a failed run never leaves a partial map.
"""

import json
import os
import tempfile

import numpy as np

SCHEMA_VERSION = 1


def map_to_dict(segments, polylines, closed=None, support=None, stats=None, config=None,
                frame_id: str = 'map') -> dict:
    """Build the JSON-ready dict of a map (floats rounded to 0.1 mm)."""
    segs = np.asarray(segments, dtype=float).reshape(-1, 4)
    out = {
        'schema_version': SCHEMA_VERSION,
        'frame_id': frame_id,
        'segments': np.round(segs, 4).tolist(),
        'polylines': [np.round(np.asarray(p, dtype=float), 4).tolist() for p in polylines],
        'closed': [bool(c) for c in (closed if closed is not None else [False] * len(polylines))],
    }
    if support is not None:
        out['support'] = np.round(np.asarray(support, dtype=float), 2).tolist()
    out['stats'] = dict(stats or {})
    if config is not None:
        out['config'] = dict(config)
    return out


def write_json_atomic(path: str, data: dict) -> None:
    """Write JSON to ``path`` through a temporary file in the same folder."""
    write_text_atomic(path, dumps_map(data))


def write_text_atomic(path: str, text: str) -> None:
    """Write text (UTF-8) to ``path`` through a temporary file in the same folder, renamed."""
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix='.tmp-', suffix=os.path.splitext(path)[1], dir=folder)
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as fh:
            fh.write(text)
        set_default_mode(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def dumps_map(data: dict) -> str:
    """JSON text with one top-level key per line and compact values (diff- and eye-friendly)."""
    rows = [f'  {json.dumps(k)}: {json.dumps(v, separators=(", ", ": "), allow_nan=False)}'
            for k, v in data.items()]
    return '{\n' + ',\n'.join(rows) + '\n}\n'


def set_default_mode(path: str) -> None:
    """Give a file made by mkstemp (mode 0600) the mode a plain open() would have."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)


def read_map(path: str) -> dict:
    """Read and check a map JSON file; raise ValueError naming what is wrong."""
    try:
        with open(path, 'r', encoding='utf-8') as fh:
            data = json.load(fh)
    except FileNotFoundError:
        raise ValueError(f'{path}: no such file') from None
    except (OSError, ValueError) as exc:
        raise ValueError(f'{path}: not a readable map JSON ({exc})') from None
    if not isinstance(data, dict):
        raise ValueError(f'{path}: a map JSON must be an object')
    for key in ('frame_id', 'segments', 'polylines'):
        if key not in data:
            raise ValueError(f'{path}: missing key "{key}"')
    segs = np.asarray(data['segments'], dtype=float)
    if segs.size and (segs.ndim != 2 or segs.shape[1] != 4 or not np.isfinite(segs).all()):
        raise ValueError(f'{path}: "segments" must be a list of [x1, y1, x2, y2]')
    data['segments_array'] = segs.reshape(-1, 2, 2)
    return data
