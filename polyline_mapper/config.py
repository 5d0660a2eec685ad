"""
Fit and mapper configuration from files and ``--set``, read through the parameter table.

One table (``params.all_params``) names every setting of the batch fit (``smemsf.*``) and of
the incremental mapper (``incremental.*``) with its type and range; the node declares its
parameters from it, and the command line reads config files and ``--set key=value`` through it,
so a value means the same and is checked the same way everywhere.

A config file is YAML (or JSON): either a flat mapping of field names (``sigma: 0.03``,
``buffer_scans: 5``) or a ROS 2 parameter file (``<node>: ros__parameters: {...}``) whose
``smemsf.*`` / ``incremental.*`` entries (dotted, or nested blocks, or plain field names) are
used; ``replay`` also takes the node parameters that place and group the scans from it
(``read_node_file``, ``REPLAY_READS``), as the node with that file would. Numbers
written as text (``1e-3``, which YAML reads as a string) are numbers; a field that defaults to
"automatic" (None) takes ``none``.
"""

from dataclasses import replace
import math
from typing import Iterable, NamedTuple, Optional

from .core.incremental import IncrementalConfig
from .core.smemsf import SMEMSFConfig
from .params import all_params, check_value, NODE_NAME

GROUPS = ('smemsf', 'incremental')
_EXPECTED = {bool: 'true or false', int: 'an integer', float: 'a finite number',
             str: 'a string'}


class ConfigError(ValueError):
    """A configuration that cannot be used (one line naming the file or --set, and the key)."""


def table(groups: Iterable[str] = GROUPS) -> dict:
    """Return {field name: ParamSpec} of the parameter table's entries in ``groups``."""
    out = {}
    for spec in all_params():
        group, _, name = spec.name.partition('.')
        if group in groups and name:
            out[name] = spec
    return out


def typed_value(spec, value, origin: str):
    """
    Return ``value`` (a --set string or a YAML value) as the type of table entry ``spec``.

    Text numbers become numbers; an optional entry (None means "estimate it") takes
    none / null. The value is then checked against the entry's range and choices. Raises
    ConfigError naming ``origin``, the key and what is expected.
    """
    key = spec.name.partition('.')[2] or spec.name
    base = type(spec.default)
    text = value.strip() if isinstance(value, str) else None
    if spec.optional and (value is None or (text is not None
                                            and text.lower() in ('none', 'null', '~', ''))):
        return None
    try:
        if base is bool:
            out = value if isinstance(value, bool) else {'true': True, 'false': False}[
                (text or '').lower()]
        elif base is str:
            if not isinstance(value, str):
                raise ValueError
            out = value
        else:
            if isinstance(value, bool) or not isinstance(value, (int, float, str)):
                raise ValueError
            number = float(text) if text is not None else value
            if not math.isfinite(number):
                raise ValueError
            if base is int:
                if number != int(number):
                    raise ValueError
                out = (int(text) if text is not None and text.lstrip('+-').isdigit()
                       else int(number))
            else:
                out = float(number)
    except (ValueError, KeyError, OverflowError):
        expected = _EXPECTED[base] + (' or none' if spec.optional else '')
        raise ConfigError(f'{origin}: {key} must be {expected}, got {value!r}') from None
    try:
        check_value(spec, out)
    except ValueError as exc:
        raise ConfigError(f'{origin}: {exc}') from None
    return out


def _node_blocks(data: dict, prefix: str = '', depth: int = 0) -> list:
    """Return (name, ros__parameters) of every node block, namespaces nested or in the key."""
    out = []
    for key, value in data.items():
        if not isinstance(value, dict) or depth > 16:
            continue
        name = f'{prefix}/{str(key).strip("/")}'
        if 'ros__parameters' in value:
            out.append((name, value['ros__parameters']))
        else:
            out.extend(_node_blocks(value, name, depth + 1))
    return out


def _ros_parameters(data: dict, path: str):
    """Return the ``ros__parameters`` of a ROS 2 parameter file's node block, else None (flat)."""
    return _our_block(data, path)[0]


def _our_block(data: dict, path: str) -> tuple:
    """
    Return (``ros__parameters`` of this node's block or None (flat), other blocks' names).

    A file with several nodes' blocks (a whole robot's, Nav2's style) gives this node's:
    the one block named ``polyline_mapper_node`` (in any namespace) or ``/**``, both merged
    when there are both (the named one wins, as for the node). Several robots' blocks
    (/robot1/polyline_mapper_node, /robot2/...) are refused, naming them: which one is meant
    cannot be told.
    """
    blocks = _node_blocks(data)
    if not blocks:
        return None, []
    ours = [(n, p) for n, p in blocks if n.rsplit('/', 1)[-1] in ('**', NODE_NAME)]
    if len(blocks) == 1:
        ours = blocks
    wild = [b for b in ours if b[0] == '/**']
    named = [b for b in ours if b[0] != '/**']
    if len(named) > 1 or not ours:
        names = ', '.join(n for n, _ in (named if named else blocks))
        why = (f'{len(named)} blocks for this node' if named
               else f'{len(blocks)} node blocks, none named {NODE_NAME} or /**')
        raise ConfigError(f'{path}: {why} ({names}): keep the one to read in a file of its own')
    params = {}
    for _, block in wild + named:
        block = block or {}
        if not isinstance(block, dict):
            raise ConfigError(f'{path}: ros__parameters must be a mapping')
        _merge(params, block)
    read = {n for n, _ in ours}
    return params, [n for n, _ in blocks if n not in read]


def _merge(into: dict, block: dict) -> None:
    """Merge parameter block ``block`` into ``into``, nested groups key by key."""
    for key, value in block.items():
        if isinstance(value, dict) and isinstance(into.get(key), dict):
            into[key] = dict(into[key])
            _merge(into[key], value)
        else:
            into[key] = value


def _file_values(data: dict, keys: dict, path: str) -> dict:
    """Return the table keys of a flat mapping or of a ROS 2 parameter file's node block."""
    params = _ros_parameters(data, path)
    if params is None:
        return dict(data)
    out = {}
    for key, value in params.items():
        group, _, name = str(key).partition('.')
        if group in GROUPS and isinstance(value, dict) and not name:
            _known(group, value, path)
            out.update({k: v for k, v in value.items() if k in keys})           # nested block
        elif group in GROUPS:
            _known(group, {name: value}, path)
            if name in keys:
                out[name] = value                                               # dotted
        elif key in keys:
            out[key] = value                                                    # plain
    return out


REPLAY_READS = ('fixed_frame', 'pose_source', 'scan_matching', 'odom_frame', 'chord_knots',
                'transform_tolerance', 'transform_timeout', 'transform_cache', 'laser_x',
                'laser_y', 'laser_yaw', 'laser_upside_down', 'odom_gap_factor',
                'scan_time_offset', 'update_every_n_scans', 'grid_resolution',
                'map_input_path', 'initial_pose', 'mapping')
"""Node parameters ``replay --config`` maps with, as the node would (``read_node_file``);
the others only shape the live node's outputs, queues and timers."""


class NodeFile(NamedTuple):
    """What a ROS 2 parameter file (and ``replay --set``) says of the node's own parameters."""

    settings: Optional[object] = None
    """``params.NodeSettings`` of the file, as the node takes it (None: no node block)."""
    names: tuple = ()
    """The node parameters it sets: the file's off their defaults, every ``--set`` one."""
    live_only: tuple = ()
    """'name: value' of those ``replay`` does not take (``REPLAY_READS``): outputs, timers."""
    unknown: tuple = ()
    """Names that are no parameter of the node, each with a hint (``params.unknown_params``)."""
    skipped: tuple = ()
    """Other nodes' blocks of the file, not read (a node under another name reads its own)."""
    states: bool = False
    """Whether the file (or ``--set``) gives any of the node's own parameters, even at its
    default (a robot's file; not one of only ``smemsf`` / ``incremental`` entries)."""


def read_node_file(path: str = None, overrides: dict = None, map_path: str = None) -> NodeFile:
    """
    Return what a ROS 2 parameter file says of the node's own parameters (``NodeFile``).

    The settings are the node's with that file (``params.settings_from``: the same checks, and
    a ``map_input_path`` turns ``scan_matching`` on), with ``overrides`` ({name: value}, typed:
    ``replay --set``) over it; ``map_path`` (``replay --map``) stands for ``map_input_path``.
    A number with no decimal point for a double parameter (``laser_yaw: 1``) is refused, as
    the node refuses it (a ROS 2 parameter's type is the YAML value's). A flat config and no
    overrides give ``NodeFile()``. Raises ConfigError (one line naming the file) for a value
    the node would refuse.
    """
    import yaml
    from .params import NODE_PARAMS, settings_from, unknown_params
    overrides = dict(overrides or {})
    params, skipped = None, []
    if path:
        try:
            with open(path, 'r', encoding='utf-8') as fh:
                data = yaml.safe_load(fh) or {}
        except (OSError, UnicodeDecodeError, yaml.YAMLError):
            data = None          # read_values, which reads the file first, says why
        if isinstance(data, dict):
            params, skipped = _our_block(data, path)
    if params is None and not overrides:
        return NodeFile()
    specs = {spec.name: spec for spec in NODE_PARAMS}
    given, others = {}, []
    for key, value in (params or {}).items():
        key = str(key)
        if key in specs:
            given[key] = value
        elif key == 'qos_overrides' or key.partition('.')[0] in GROUPS:
            continue            # the middleware's; the groups' keys are checked when read
        elif isinstance(value, dict):
            others += [f'{key}.{k}' for k in value]
        else:
            others.append(key)
    for key, value in given.items():
        _double_typed(specs[key], value, path)
    values = {spec.name: spec.default for spec in all_params()}
    values.update(given)
    values.update(overrides)
    if map_path:
        values['map_input_path'] = str(map_path)
    try:
        settings, _ = settings_from(values)
    except ValueError as exc:
        raise ConfigError(f'{path or "--set"}: {exc}') from None
    names = [k for k, v in given.items() if not _same(v, specs[k].default)]
    names += [k for k in overrides if k not in names]
    live = tuple(f'{k}: {_yaml_text(given[k])}' for k in names
                 if k not in REPLAY_READS and k in given)
    return NodeFile(settings, tuple(names), live, tuple(unknown_params(others)), tuple(skipped),
                    bool(given or overrides))


def _double_typed(spec, value, path: str) -> None:
    """Raise ConfigError for an integer YAML value of a double (or double array) parameter."""
    d = spec.default
    ints = (isinstance(d, float) and isinstance(value, int) and not isinstance(value, bool)) or (
        isinstance(d, (list, tuple)) and d and isinstance(d[0], float)
        and isinstance(value, (list, tuple))
        and any(isinstance(v, int) and not isinstance(v, bool) for v in value))
    if ints:
        fixed = ([float(v) for v in value] if isinstance(value, (list, tuple))
                 else float(value))
        raise ConfigError(f'{path}: {spec.name} is {_yaml_text(value)}, an integer where the node '
                          f'takes a double (ROS 2 parameter types follow the YAML): write '
                          f'{_yaml_text(fixed)}')


def _yaml_text(value) -> str:
    """Return ``value`` as YAML writes it (true, not True)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_yaml_text(v) for v in value) + ']'
    return str(value)


def _same(value, default) -> bool:
    """Whether a parameter file's ``value`` is the parameter's ``default``."""
    if isinstance(default, float) and isinstance(value, (int, float)) and \
            not isinstance(value, bool):
        return math.isclose(float(value), default) or value == default
    if isinstance(default, (list, tuple)) and isinstance(value, (list, tuple)):
        return len(value) == len(default) and all(_same(v, d) for v, d in zip(value, default))
    return value == default


def _known(group: str, values: dict, path: str) -> None:
    """Raise ConfigError for a key of ``values`` that is no parameter of ``group`` (a typo)."""
    known = table((group,))
    for name in values:
        if name not in known:
            raise ConfigError(f'{path}: unknown parameter {group}.{name} (the {group} '
                              f'parameters: {", ".join(sorted(known))})')


def read_values(path: str = None, overrides: Iterable[str] = (),
                groups: Iterable[str] = GROUPS, extra: Iterable[str] = (),
                also: Iterable[str] = ()) -> dict:
    """
    Read a config file and ``key=value`` overrides; return {field name: typed value}.

    Only the table's entries of ``groups`` (and the field names ``extra`` of other groups) are
    accepted; anything else is a ConfigError that lists the accepted keys, with the nearest as
    "did you mean". ``also``: keys the caller takes itself (``replay --set``'s node
    parameters), listed and suggested with them.
    """
    keys = table(groups)
    keys.update({k: v for k, v in table().items() if k in set(extra)})
    raw = {}
    if path:
        import yaml
        try:
            with open(path, 'r', encoding='utf-8') as fh:
                data = yaml.safe_load(fh) or {}
        except FileNotFoundError:
            raise ConfigError(f'{path}: no such config file') from None
        except yaml.MarkedYAMLError as exc:     # where and what, as the YAML parser says it
            mark = exc.problem_mark
            where = '' if mark is None else f' at line {mark.line + 1}, column {mark.column + 1}'
            what = ' '.join(str(exc.problem or exc.__class__.__name__).split())
            raise ConfigError(f'{path}: not valid YAML{where}: {what}') from None
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise ConfigError(f'{path}: unreadable config ({exc.__class__.__name__})') from None
        if not isinstance(data, dict):
            raise ConfigError(f'{path}: a config file must hold a mapping')
        raw.update({k: (v, path) for k, v in _file_values(data, keys, path).items()})
    for item in overrides:
        key, sep, value = item.partition('=')
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f'--set expects key=value, got {item!r}')
        raw[key] = (value, f'--set {item}')
    unknown = sorted(k for k in raw if k not in keys)
    if unknown:
        import difflib
        names = sorted(set(keys) | set(also))
        near = difflib.get_close_matches(unknown[0], names, n=1)
        raise ConfigError(f'{raw[unknown[0]][1]}: unknown key {unknown[0]!r} ('
                          f'{f"did you mean {near[0]}? " if near else ""}keys: '
                          f'{", ".join(names)})')
    return {k: typed_value(keys[k], v, origin) for k, (v, origin) in raw.items()}


def load_fit_config(path: str = None, overrides: Iterable[str] = ()) -> SMEMSFConfig:
    """Return the batch fit's SMEMSFConfig from a config file and --set overrides."""
    values = read_values(path, overrides, ('smemsf',))
    try:
        return SMEMSFConfig.from_dict(values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f'bad config: {exc}') from None


FIT_EXTRA = ('free_space_window', 'free_space_hit_margin')
"""Mapper keys the batch fit (``fit``) reads too: ``free_space_window`` > 0 fits a log's,
bag's or drive's points with their beams (``smemsf.fit(points, origins=...)``), with the
mapper's ``free_space_hit_margin``."""


def load_fit_options(path: str = None, overrides: Iterable[str] = ()) -> tuple:
    """
    Return (SMEMSFConfig, free-space options) of the batch fit from a config file and --set.

    As ``load_fit_config``, plus the mapper's ``free_space_window`` and
    ``free_space_hit_margin`` (``incremental.`` in a ROS 2 parameter file), as a dict of
    ``smemsf.fit`` keywords, the mapper's defaults unless given (window -1: ``AUTO_WINDOW``, 10;
    margin 0.03): N > 0 fits a recording's beams with their evidence decaying over N looks, as
    ``replay --set free_space_window=N``; window 0 fits the bare points.
    """
    values = read_values(path, overrides, ('smemsf',), FIT_EXTRA)
    mapper = IncrementalConfig()
    window = values.pop('free_space_window', mapper.free_space_window)
    # The batch fit has its poses given: the mapper's own rule for the window's -1.
    extra = {'free_space_window': replace(mapper, free_space_window=window).resolved()
             .free_space_window,
             'free_space_hit_margin': values.pop('free_space_hit_margin',
                                                 mapper.free_space_hit_margin)}
    try:
        return SMEMSFConfig.from_dict(values), extra
    except (TypeError, ValueError) as exc:
        raise ConfigError(f'bad config: {exc}') from None


def load_mapper_config(path: str = None, overrides: Iterable[str] = (),
                       also: Iterable[str] = ()) -> IncrementalConfig:
    """
    Return the incremental mapper's IncrementalConfig from a config file and overrides.

    ``also``: the other keys the caller's ``--set`` takes (``read_values``).
    """
    values = read_values(path, overrides, also=also)
    inc_keys = table(('incremental',))
    inc = {k: values.pop(k) for k in list(values) if k in inc_keys}
    try:
        return IncrementalConfig(smemsf=SMEMSFConfig.from_dict(values), **inc)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f'bad config: {exc}') from None
