"""
Start-up of a node process: ROS arguments and parameter files checked, rclpy started, one line.

rcl refuses bad command-line ROS arguments inside ``rclpy.init`` with an RCLError (after logging
its own "Failed to parse global arguments" line), so a missing, broken or binary
``--params-file`` or an empty ``-p name:=`` ends in a 13-line traceback. ``check_ros_args``
finds these before rcl does and says what is wrong in our words (the choices of a parameter
given no value, the line of a YAML error); ``init`` starts rclpy and turns whatever rcl still
refuses into one line, without rcl's own log line. Callers log ``cannot start: <reason>`` and
exit with code 1, as for a bad parameter value. ``read_start_map`` reads the saved map of
``map_input_path`` the same way: a missing, unreadable or broken file is one line.
"""

import os
import re
import sys
import tempfile
from typing import Optional, Sequence

from ..params import all_params

MAX_PARAMS_FILE = 16 << 20
"""Largest parameter file read for checking (bytes); rcl reads larger ones itself."""


class StartupError(ValueError):
    """A reason the node (or a command-line tool's rclpy context) cannot start, in one line."""


def ros_arg_sections(argv: Sequence[str]) -> list:
    """Return the ROS arguments of ``argv``: those after each ``--ros-args`` up to ``--``."""
    out, inside = [], False
    for arg in argv:
        if arg == '--ros-args':
            inside = True
        elif arg == '--':
            inside = False
        elif inside:
            out.append(arg)
    return out


def check_ros_args(argv: Sequence[str]) -> None:
    """
    Raise StartupError with one line when a ROS argument of ``argv`` cannot work.

    Checked: ``-p`` / ``--param`` rules with an empty value (rcl refuses them; a parameter
    with choices names them, fixed_frame asks for a frame name), and each ``--params-file``:
    it exists, is a readable regular file, is text and parses as YAML. What passes here is
    still checked by rcl and by the node's parameter validation.
    """
    args = ros_arg_sections(argv)
    specs = {p.name: p for p in all_params()}
    for flag, value in zip(args, args[1:] + ['']):
        if flag in ('-p', '--param'):
            _check_rule(value, specs)
        elif flag == '--params-file':
            check_params_file(value)


def _check_rule(rule: str, specs: dict) -> None:
    name, sep, value = rule.partition(':=')
    name = name.rpartition(':')[2]              # '-p node_name:param:=' names a node
    if sep and value:
        _check_type(name, value, rule, specs)   # then rcl's checks (and the node's) apply
    if not sep or value:
        return
    spec = specs.get(name)
    if spec is not None and spec.choices:
        raise StartupError(f'{name} must be one of {", ".join(spec.choices)}, got an empty '
                           f'value (-p {rule})')
    if name == 'fixed_frame':
        raise StartupError(f'fixed_frame must be a frame name (e.g. map), got an empty value '
                           f'(-p {rule})')
    if spec is not None and spec.default == '':
        raise StartupError(f'{name}: no value after ":=" (-p {rule}); leave the parameter out '
                           'for none')
    if spec is not None and isinstance(spec.default, str):
        raise StartupError(f'{name} must not be empty (-p {rule})')
    kind = f' ({name} takes a {type(spec.default).__name__})' if spec is not None else ''
    raise StartupError(f'-p {rule}: no value after ":="{kind}')


def _check_type(name: str, value: str, rule: str, specs: dict) -> None:
    """
    Refuse a value of the wrong kind for a number, a whole number or a switch.

    E.g. ``-p smemsf.range_noise:=abc``, or ``-p incremental.buffer_scans:=5.0`` for an
    integer. The node refuses it alone, but beside a ``--params-file`` that sets the parameter rcl
    keeps the file's value without a word (a new-user audit lost its setting that way).
    """
    spec = specs.get(name)
    if spec is None or isinstance(spec.default, (str, list, tuple)):
        return
    text = value.strip()
    if text[:1] == '[':
        kind = 'a list'
    elif len(text) >= 2 and text[0] == text[-1] and text[0] in '"\'':
        kind = 'the text ' + text
    elif text.lower() in ('true', 'false', 'yes', 'no', 'on', 'off'):
        kind = 'a switch'
    else:
        try:
            float(text)
            kind = 'a number'
        except ValueError:
            kind = f'the text {text!r}'
    want = 'a switch' if isinstance(spec.default, bool) else 'a number'
    if kind != want:
        need = 'true or false' if want == 'a switch' else 'a number'
        raise StartupError(f'{name} takes {need}, got {kind} (-p {rule}; beside a '
                           "--params-file rcl would keep the file's value)")
    # rcl types a number by its spelling: with a point or an exponent a double, which an
    # integer parameter drops without a word beside a params file (alone the node refuses it;
    # an integer for a double parameter the node refuses either way, with the remedy)
    if (want == 'a number' and isinstance(spec.default, int)
            and _INTEGER.fullmatch(text) is None):
        raise StartupError(f'{name} takes a whole number, got {text} (-p {rule}; beside a '
                           "--params-file rcl would keep the file's value)")


_INTEGER = re.compile(r'[+-]?[0-9]+')
"""A whole number as rcl's parameter parser reads one (a number without a point or an exponent;
hexadecimal never gets here: float() refused it as text above)."""


def check_params_file(path: str) -> None:
    """Raise StartupError when ``path`` is not a readable YAML text file."""
    if not path:
        raise StartupError('--params-file needs a file name')
    what = f'params file {path}'
    if not os.path.exists(path):
        raise StartupError(f'{what}: no such file')
    if os.path.isdir(path):
        raise StartupError(f'{what}: is a directory, not a YAML file')
    if not os.path.isfile(path):
        raise StartupError(f'{what}: not a regular file')
    try:
        with open(path, 'rb') as fh:
            data = fh.read(MAX_PARAMS_FILE + 1)
    except OSError as exc:
        raise StartupError(f'{what}: cannot be read ({exc.strerror or exc})') from None
    if len(data) > MAX_PARAMS_FILE:
        return                                  # too big to check here: rcl reads it
    if b'\0' in data:
        raise StartupError(f'{what}: binary data (a NUL byte at byte {data.index(0)}), not '
                           'a YAML text file')
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise StartupError(f'{what}: not UTF-8 text (byte {exc.start}), not a YAML text '
                           'file') from None
    try:
        import yaml
    except ImportError:                         # pragma: no cover - rclpy depends on PyYAML
        return
    try:
        yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
        problem = getattr(exc, 'problem', None) or 'cannot be parsed'
        raise StartupError(f'{what}: not valid YAML ({problem}{where})') from None
    except RecursionError:
        raise StartupError(f'{what}: not valid YAML (nested too deep)') from None


def read_start_map(path: str):
    """
    Return the saved map at ``path`` (``formats.mapjson.MapFile``), or None for ''.

    StartupError with one line naming ``map_input_path`` when it is missing, not a regular
    file, unreadable, not a map JSON or a broken one (``read_map``'s checks).
    """
    if not path:
        return None
    from ..formats.mapjson import read_map
    try:
        return read_map(path)
    except ValueError as exc:
        raise StartupError(f'map_input_path {exc}') from None


def init(args: Optional[Sequence[str]] = None, **kwargs) -> None:
    """
    Check the ROS arguments, then start rclpy with them (and kwargs); StartupError if not.

    rcl's own log line about arguments it refuses is held back (standard error is captured
    while rcl parses them) and its error becomes the StartupError's one line.
    """
    import rclpy
    argv = list(sys.argv if args is None else args)
    check_ros_args(argv)
    try:
        with _stderr_held() as held:
            rclpy.init(args=args, **kwargs)
    except Exception as exc:                    # noqa: B902 - RCLError and friends
        raise StartupError(rcl_reason(exc)) from None
    if held.text:
        sys.stderr.write(held.text)


def rcl_reason(exc: BaseException) -> str:
    """Return a one-line reason from an exception of ``rclpy.init`` (RCLError and others)."""
    name = type(exc).__name__
    text = ' '.join(str(exc).split())
    if name == 'UnknownROSArgsError':
        found = re.findall(r"'([^']*)'", text)
        return f'unknown ROS argument(s): {" ".join(found) or text}'
    text = re.sub(r', at [^,]*?\.\w+:\d+', '', text)      # rcl's source locations
    text = text.replace('failed to initialize rcl: ', '')
    text = re.sub(r'\.? ?Error: error not set', '', text)
    params = re.match(r"Couldn't parse params file: '--params-file (.*?)'\. Error: (.*)", text)
    if params:
        return f'params file {params.group(1)}: {params.group(2)}'
    return text or name


class _Held:
    text = ''


class _stderr_held:
    """Capture file descriptor 2 (where rcl logs) while rcl parses the arguments."""

    def __enter__(self) -> _Held:
        self.held = _Held()
        try:
            sys.stderr.flush()
            self.saved = os.dup(2)
        except (OSError, ValueError):
            self.saved = None                   # no usable fd 2: nothing to hold
            return self.held
        self.tmp = tempfile.TemporaryFile()
        os.dup2(self.tmp.fileno(), 2)
        return self.held

    def __exit__(self, *exc) -> bool:
        if self.saved is None:
            return False
        os.dup2(self.saved, 2)
        os.close(self.saved)
        self.tmp.seek(0)
        self.held.text = self.tmp.read().decode(errors='replace')
        self.tmp.close()
        return False
