"""Point files: .npy, .csv and whitespace .txt with two columns x y (metres)."""

import math
import os
from tokenize import TokenError
import warnings

import numpy as np

from ..core.geometry import as_points

MAX_COORDINATE = 1e8
"""Largest coordinate magnitude accepted (m): beyond any Earth-bound frame (UTM northings
reach 1e7 m, the Earth's circumference is 4e7 m); larger values are corrupt data."""


def check_coordinates(points: np.ndarray, name: str) -> np.ndarray:
    """
    Return ``points`` ((N, 2) float, metres) if every coordinate is within +-MAX_COORDINATE.

    Raises ValueError naming the first offending row otherwise.
    """
    bad = (np.abs(points) > MAX_COORDINATE).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f'{name}: {int(bad.sum())} point(s) beyond +-{MAX_COORDINATE:g} m, '
                         f'e.g. row {i}: ({points[i, 0]:g}, {points[i, 1]:g}); coordinates '
                         'must be metres of a sane magnitude')
    return points


def _npy_header(path: str) -> None:
    """
    Check an .npy header against the file before loading it.

    A header may declare any shape; loading trusts it and allocates that much. Raises
    ValueError when the declared array is not a plain numeric one or needs more bytes than
    the file holds.
    """
    fmt = np.lib.format
    size = os.path.getsize(path)
    with open(path, 'rb') as fh:
        try:
            version = fmt.read_magic(fh)
            read = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
            shape, _, dtype = read(fh)
        except (ValueError, OSError, EOFError, SyntaxError, TypeError, TokenError,
                RecursionError) as exc:
            msg = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
            raise ValueError(f'not a valid .npy file ({msg[:200]})') from None
        offset = fh.tell()
    if dtype.kind not in 'fiu' or dtype.fields is not None or dtype.subdtype is not None:
        raise ValueError(f'.npy holds {dtype}, not real numbers')
    need = math.prod(shape) * dtype.itemsize
    if need > size - offset:
        raise ValueError(f'.npy header declares shape {tuple(shape)} ({need:,} bytes of '
                         f'{dtype}) but the file holds {size - offset:,} bytes of data')


def read_points(path: str) -> np.ndarray:
    """
    Read an (N, 2) point file; raise ValueError with the reason when it cannot be used.

    .npy: a float array of shape (N, 2). .csv: comma-separated, an optional header line.
    .txt / other: whitespace-separated. Lines starting with # are comments. Coordinates must be
    finite and within +-MAX_COORDINATE metres.
    """
    if not os.path.isfile(path):
        raise ValueError(f'{path}: no such file')
    ext = os.path.splitext(path)[1].lower()
    if os.path.getsize(path) == 0:
        raise ValueError(f'{path}: empty file, no points')
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')        # "input contained no data": handled below
            if ext == '.npy':
                _npy_header(path)
                arr = np.load(path, allow_pickle=False)
            else:
                delim = ',' if ext == '.csv' else None
                # utf-8-sig: a byte-order mark (spreadsheets write one) is not part of the
                # first value, which would make the first line a "header" and drop its point
                with open(path, 'r', encoding='utf-8-sig') as fh:
                    first = fh.readline(4096)
                skip = 0
                if first.strip() and not first.lstrip().startswith('#'):
                    try:
                        [float(v) for v in first.replace(',', ' ').split()]
                    except ValueError:
                        skip = 1                               # a header line
                arr = np.loadtxt(path, delimiter=delim, skiprows=skip, ndmin=2, comments='#',
                                 encoding='utf-8-sig')
    except (OSError, ValueError, EOFError, UnicodeDecodeError, MemoryError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
        raise ValueError(f'{path}: unreadable point file ({msg})') from None
    if arr.size == 0:
        raise ValueError(f'{path}: no points (only a header or comments)')
    return check_coordinates(as_points(arr, name=f'{path}: points'), path)
