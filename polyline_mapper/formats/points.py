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


def _is_number(text: str) -> bool:
    """Return whether ``np.loadtxt`` reads ``text`` as a float (Python's float() takes more)."""
    text = text.strip()
    if not text.isascii() or '_' in text:        # '1_000', Arabic-Indic digits: loadtxt refuses
        return False
    try:
        float(text)
    except ValueError:
        return False
    return True


def _rows(path: str, skip: int, delim):
    """
    Yield ``(line number, fields)`` for each row ``np.loadtxt`` reads from a text point file.

    Line numbers count from 1 as a text editor shows them, the skipped header and comment or
    blank lines included. A row is a line after its ``#`` comment is cut off, unless nothing
    but whitespace is left (a blank line); fields are split as loadtxt does.
    """
    with open(path, 'r', encoding='utf-8-sig') as fh:
        for number, line in enumerate(fh, start=1):
            if number <= skip:
                continue
            text = line.split('#', 1)[0].rstrip('\r\n')
            if text.strip():
                yield number, (text.split(delim) if delim else text.split())


def _bad_line(path: str, skip: int, delim):
    """
    Return ``'line N...: what is wrong'`` for the first row ``np.loadtxt`` refuses, or None.

    loadtxt names the row among the rows it read, counting from 0 for a value that is no
    number and from 1 for a changed number of columns, blind to the header and comment
    lines; a user counts the file's lines from 1.
    """
    first = None
    for number, fields in _rows(path, skip, delim):
        if first is None:
            first = number, len(fields)
        elif len(fields) != first[1]:
            return (f'line {number} has {len(fields)} column(s) where line {first[0]} has '
                    f'{first[1]}')
        for column, text in enumerate(fields, start=1):
            if not _is_number(text):
                return f'line {number}, column {column}: {text.strip()[:40]!r} is not a number'
    return None


def _loadtxt_stripped(path: str, delim: str, skip: int) -> np.ndarray:
    """
    Read a delimited text point file as ``np.loadtxt`` does, each line stripped first.

    With a delimiter loadtxt reads a line of nothing but whitespace (spaces, a tab, an
    editor's trailing "   ", or spaces before a ``#`` comment) as a row of one empty value and
    refuses the file; stripped, it is an empty line, skipped as ``_rows`` skips it, and every
    line keeps its number. A value's own spaces loadtxt ignores anyway. ``map(str.strip, ...)``
    runs in C: no Python code per line (a 2-million-line .csv: 0.28 s against 0.18 s from the
    path, which is tried first).
    """
    with open(path, 'r', encoding='utf-8-sig') as fh:
        return np.loadtxt(map(str.strip, fh), delimiter=delim, skiprows=skip, ndmin=2,
                          comments='#', encoding='utf-8-sig')


def read_points(path: str) -> np.ndarray:
    """
    Read an (N, 2) point file; raise ValueError with the reason when it cannot be used.

    .npy: a float array of shape (N, 2). .csv: comma-separated, an optional header line.
    .txt / other: whitespace-separated. Lines starting with # are comments; blank lines (empty
    or nothing but whitespace) are skipped. Coordinates must be finite and within
    +-MAX_COORDINATE metres. A value that is no number, or a line with another number of
    columns, is named by its line in the file (from 1, as an editor counts).
    """
    if not os.path.isfile(path):
        raise ValueError(f'{path}: no such file')
    ext = os.path.splitext(path)[1].lower()
    if os.path.getsize(path) == 0:
        raise ValueError(f'{path}: empty file, no points')
    skip, delim = 0, None
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
                if first.strip() and not first.lstrip().startswith('#'):
                    try:
                        [float(v) for v in first.replace(',', ' ').split()]
                    except ValueError:
                        skip = 1                               # a header line
                try:
                    arr = np.loadtxt(path, delimiter=delim, skiprows=skip, ndmin=2,
                                     comments='#', encoding='utf-8-sig')
                except ValueError:
                    if delim is None:
                        raise
                    arr = _loadtxt_stripped(path, delim, skip)
    except (OSError, ValueError, EOFError, UnicodeDecodeError, MemoryError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
        if ext != '.npy' and isinstance(exc, ValueError):
            try:
                msg = _bad_line(path, skip, delim) or msg
            except (OSError, ValueError):
                pass                                # loadtxt's own words, then
        raise ValueError(f'{path}: unreadable point file ({msg})') from None
    if arr.size == 0:
        raise ValueError(f'{path}: no points (only a header or comments)')
    try:
        return check_coordinates(as_points(arr, name=f'{path}: points'), path)
    except ValueError:
        if ext != '.npy' and arr.ndim == 2 and arr.shape[1] == 2:
            _check_lines(path, arr, skip, delim)        # the same refusal, named by file line
        raise


def _check_lines(path: str, arr: np.ndarray, skip: int, delim) -> None:
    """
    Raise ValueError naming the file line of the first point not finite or beyond the limit.

    ``arr``: the (N, 2) rows ``np.loadtxt`` read from a text point file (``_rows``' order);
    the row index alone would not be the line a user finds in an editor.
    """
    with np.errstate(invalid='ignore'):
        bad = ~np.isfinite(arr).all(axis=1) | (np.abs(arr) > MAX_COORDINATE).any(axis=1)
    if not bad.any():
        return
    i = int(np.argmax(bad))
    line = next((n for k, (n, _) in enumerate(_rows(path, skip, delim)) if k == i), None)
    where = f'line {line}' if line is not None else f'row {i}'
    what = ('NaN or inf' if not np.isfinite(arr[i]).all()
            else f'beyond +-{MAX_COORDINATE:g} m (coordinates must be metres)')
    raise ValueError(f'{path}: {int(bad.sum())} point(s) NaN, inf or beyond '
                     f'+-{MAX_COORDINATE:g} m; the first on {where}: '
                     f'({arr[i, 0]:g}, {arr[i, 1]:g}) is {what}')
