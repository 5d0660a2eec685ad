"""Point files: .npy, .csv and whitespace .txt with two columns x y (metres)."""

import os

import numpy as np

from ..core.geometry import as_points


def read_points(path: str) -> np.ndarray:
    """
    Read an (N, 2) point file; raise ValueError with the reason when it cannot be used.

    .npy: a float array of shape (N, 2). .csv: comma-separated, an optional header line.
    .txt / other: whitespace-separated. Lines starting with # are comments.
    """
    if not os.path.isfile(path):
        raise ValueError(f'{path}: no such file')
    ext = os.path.splitext(path)[1].lower()
    if os.path.getsize(path) == 0:
        raise ValueError(f'{path}: empty file, no points')
    try:
        if ext == '.npy':
            arr = np.load(path, allow_pickle=False)
        else:
            delim = ',' if ext == '.csv' else None
            with open(path, 'r', encoding='utf-8') as fh:
                first = fh.readline()
            skip = 0
            if first.strip() and not first.lstrip().startswith('#'):
                try:
                    [float(v) for v in first.replace(',', ' ').split()]
                except ValueError:
                    skip = 1                                   # a header line
            arr = np.loadtxt(path, delimiter=delim, skiprows=skip, ndmin=2, comments='#')
    except (OSError, ValueError, EOFError, UnicodeDecodeError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
        raise ValueError(f'{path}: unreadable point file ({msg})') from None
    return as_points(arr, name=f'{path}: points')
