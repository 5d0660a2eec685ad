"""
Safe output files: every file the command line and the node write goes through here.

Rules (each refusal is an ``OutputError``, a ValueError with a one-line message naming the
target as the user gave it):

- Never write over an input: a target that is the same file as an input (``os.path.samefile``,
  so hard links and symlinks count) or lies inside an input folder (a rosbag2 folder).
- Never replace anything but a regular file: a directory, a device (``/dev/null``), a FIFO or a
  socket is refused, even as root.
- A symlink is followed: its target is written and the link stays a link (as a shell's ``>``
  does); a symlink loop is refused.
- A read-only file (no write permission for this user, or its owner's write bit clear, which
  root would otherwise ignore) is refused rather than silently replaced; so is a target whose
  folder (or, for a folder still to be made, its first existing ancestor) this user cannot
  write into.
- An existing file that is overwritten keeps its permission bits (0600 stays 0600) and, where
  the system allows, its owner; a new file gets 0666 minus the umask, as ``open()`` gives.
- Content goes to a temporary file in the target's folder (``.NAME.tmp-XXXX``), is flushed to
  disk and renamed over the target, so a reader never sees a partial file. Any failure removes
  the temporary file; messages name the target, never the temporary file.
- Several outputs of one run (a map JSON and its PNG) are checked together before any work and
  renamed together at the end (``OutputSet``): a failing PNG leaves no JSON behind.

A file with several hard links is replaced, not rewritten in place: its other names keep the
old content.
"""

import errno
import json
import os
import stat
import tempfile
from typing import Iterable, Optional

TMP_MARK = '.tmp-'
"""Temporary files are named ``.<target name>.tmp-XXXXXXXX``."""


class OutputError(ValueError):
    """An output that must not be written, or could not be; the message is one line."""


def _kind(mode: int) -> Optional[str]:
    """Name what a non-regular file is, or None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    for test, name in ((stat.S_ISDIR, 'a directory'), (stat.S_ISCHR, 'a character device'),
                       (stat.S_ISBLK, 'a block device'), (stat.S_ISFIFO, 'a FIFO (named pipe)'),
                       (stat.S_ISSOCK, 'a socket')):
        if test(mode):
            return name
    return 'not a regular file'


def _inputs(inputs: Iterable) -> list:
    """Return the given input paths that exist, as strings (None and '' dropped)."""
    return [os.fspath(p) for p in inputs or () if p is not None and os.fspath(p) != ''
            and os.path.exists(p)]


def check_output(path, inputs: Iterable = ()) -> str:
    """
    Check that ``path`` may be written; return the file to write (a symlink's target).

    ``inputs``: the paths this run reads (files or folders); missing ones are ignored. Raises
    OutputError (a ValueError, one line) when the rules in the module docstring forbid it.
    Creates nothing.
    """
    if path is None or os.fspath(path) == '':
        raise OutputError('empty output file name')
    path = os.fspath(path)
    name = path
    if path.endswith(os.sep) or os.path.basename(os.path.normpath(path)) in ('', '.', '..'):
        raise OutputError(f'{name}: names a folder, not a file to write')
    target = os.path.realpath(path)
    try:
        st = os.stat(target)
    except (FileNotFoundError, NotADirectoryError):
        st = None                              # a missing file (or a file as its folder: below)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputError(f'{name}: symlink loop; refusing to write') from None
        raise OutputError(f'{name}: cannot write ({exc.strerror or exc})') from None
    if st is not None:
        kind = _kind(st.st_mode)
        if kind is not None:
            raise OutputError(f'{name}: is {kind}, not a regular file; refusing to replace it')
        for src in _inputs(inputs):
            if os.path.samefile(src, target):
                raise OutputError(f'{name}: is an input of this run; refusing to write over it')
    # An input (the file itself, or one inside an input folder) before a read-only file: a
    # read-only input's own message advised removing it (two reviews, 2026-12-02).
    _check_inside(name, target, inputs)
    if st is not None and (not os.access(target, os.W_OK) or not st.st_mode & stat.S_IWUSR):
        raise OutputError(f'{name}: read-only file (mode {stat.S_IMODE(st.st_mode):04o}); '
                          'refusing to replace it (make it writable or remove it first)')
    _check_folder(name, target)
    return target


def _check_inside(name, target: str, inputs: Iterable) -> None:
    """Refuse a target inside an input folder."""
    for src in _inputs(inputs):
        if os.path.isdir(src):
            folder = os.path.realpath(src)
            if os.path.commonpath([folder, target]) == folder:
                raise OutputError(f'{name}: lies inside the input folder {src}; refusing to '
                                  'write into it')


def _check_folder(name, target: str) -> None:
    """Refuse a target whose first existing ancestor is no folder, or one it cannot write."""
    folder = os.path.dirname(target)
    while not os.path.exists(folder):
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise OutputError(f'{name}: {folder} is not a folder')
    if not os.access(folder, os.W_OK | os.X_OK):
        # Checked here, before the work: the write itself would fail only at the end of it.
        raise OutputError(f'{name}: cannot write into {folder} (Permission denied)')


def check_outputs(paths: Iterable, inputs: Iterable = ()) -> list:
    """
    Check several outputs of one run (None entries skipped); return their files to write.

    Also refuses two outputs that name the same file.
    """
    seen = {}
    out = []
    for path in paths:
        if path is None:
            continue
        target = check_output(path, inputs)
        if target in seen:
            raise OutputError(f'{path}: named twice as an output (also as {seen[target]})')
        seen[target] = path
        out.append(target)
    return out


def check_new_folder(path, inputs: Iterable = ()) -> str:
    """
    Check that ``path`` may be created as a new folder (e.g. a rosbag2); return its real path.

    Refuses an existing path of any kind (a folder is never merged into or replaced), one
    inside an input folder, and a parent that is not a folder.
    """
    if path is None or os.fspath(path) == '':
        raise OutputError('empty output folder name')
    path = os.fspath(path)
    for src in _inputs(inputs):
        if os.path.lexists(path) and os.path.samefile(src, path):
            raise OutputError(f'{path}: is an input of this run; refusing to write over it')
    if os.path.lexists(path):
        raise OutputError(f'{path}: exists already (a bag is written to a new folder)')
    target = os.path.realpath(path)
    _check_inside(path, target, inputs)
    _check_folder(path, target)
    return target


def _default_mode() -> int:
    """Return the mode ``open()`` gives a new file: 0666 minus the umask."""
    try:                               # read it without changing it (other threads may create)
        with open('/proc/self/status') as fh:
            umask = next(int(line.split()[1], 8) for line in fh if line.startswith('Umask:'))
    except (OSError, StopIteration, ValueError, IndexError):
        umask = os.umask(0)
        os.umask(umask)
    return 0o666 & ~umask


class OutputSet:
    """
    Outputs of one run, written all or nothing.

    ``add`` checks a target (call it for every output before the work that makes them);
    ``put`` writes one output's content to a temporary file next to its target; ``commit``
    renames them all over their targets; ``discard`` (or leaving the ``with`` block by an
    exception) removes the temporary files. Example::

        with OutputSet(inputs=[args.input]) as out:
            out.add(json_path)
            out.add(png_path)
            ... compute ...
            out.put(png_path, png_bytes)
            out.put(json_path, text)
        # both renamed here; on an exception neither exists

    Renaming is the last step and happens in the order of ``put``; it cannot fail for the
    rules above (they are checked again just before), only for an outside change of the
    folder between two renames.
    """

    def __init__(self, inputs: Iterable = ()):
        self.inputs = list(inputs or ())
        self._targets = {}          # user path -> file to write
        self._staged = []           # (user path, target, temporary file)

    def add(self, path) -> Optional[str]:
        """Check ``path`` (None: nothing to do) against the rules and the other outputs."""
        if path is None:
            return None
        path = os.fspath(path)
        target = check_output(path, self.inputs)
        for other, t in self._targets.items():
            if t == target:
                raise OutputError(f'{path}: named twice as an output (also as {other})')
        self._targets[path] = target
        return target

    def put(self, path, content) -> None:
        """Write ``content`` (str as UTF-8, or bytes) to a temporary file beside ``path``."""
        path = os.fspath(path)
        target = self._targets.get(path) or self.add(path)
        data = content.encode('utf-8') if isinstance(content, str) else bytes(content)
        folder = os.path.dirname(target)
        tmp = None
        try:
            os.makedirs(folder, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f'.{os.path.basename(target)}{TMP_MARK}',
                                       dir=folder)
            with os.fdopen(fd, 'wb') as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            _copy_mode(target, tmp)
        except OSError as exc:
            if tmp is not None:
                _unlink(tmp)
            raise OutputError(f'{path}: cannot write ({exc.strerror or exc})') from None
        except BaseException:
            if tmp is not None:
                _unlink(tmp)
            raise
        self._staged.append((path, target, tmp))

    def commit(self) -> None:
        """Rename every staged file over its target (the rules checked once more first)."""
        try:
            for path, _, _ in self._staged:
                check_output(path, self.inputs)
            while self._staged:
                path, target, tmp = self._staged[0]
                try:
                    os.replace(tmp, target)
                except OSError as exc:
                    raise OutputError(f'{path}: cannot write ({exc.strerror or exc})') from None
                self._staged.pop(0)
        finally:
            self.discard()

    def discard(self) -> None:
        """Remove the temporary files not renamed yet."""
        for _, _, tmp in self._staged:
            _unlink(tmp)
        self._staged = []

    def __enter__(self) -> 'OutputSet':
        """Start a set of outputs."""
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        """Commit when the block ran through, else remove the temporary files."""
        if exc_type is None:
            self.commit()
        else:
            self.discard()


def _copy_mode(target: str, tmp: str) -> None:
    """Give ``tmp`` the permission bits (and owner, if allowed) of ``target``, or the default."""
    try:
        st = os.stat(target)
    except FileNotFoundError:
        os.chmod(tmp, _default_mode())
        return
    os.chmod(tmp, stat.S_IMODE(st.st_mode) & 0o777)
    if (st.st_uid, st.st_gid) != (os.geteuid(), os.getegid()):
        try:
            os.chown(tmp, st.st_uid, st.st_gid)
        except OSError:
            pass                     # not allowed (not root): the file becomes ours


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def write_bytes_atomic(path, data: bytes, inputs: Iterable = ()) -> None:
    """Write bytes to ``path`` under the rules above (OutputError on a refusal or failure)."""
    with OutputSet(inputs) as out:
        out.put(path, data)


def write_text_atomic(path, text: str, inputs: Iterable = ()) -> None:
    """Write text (UTF-8) to ``path`` under the rules above (OutputError on failure)."""
    write_bytes_atomic(path, text.encode('utf-8'), inputs)


def write_json_atomic(path, data, inputs: Iterable = (), indent: int = None) -> None:
    """
    Write ``data`` as strict JSON (no NaN / Infinity: ValueError) under the rules above.

    For a map JSON use ``formats.mapjson.write_map``, which keeps the map file's layout.
    """
    write_text_atomic(path, json.dumps(data, allow_nan=False, indent=indent) + '\n', inputs)
