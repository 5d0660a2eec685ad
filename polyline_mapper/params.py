"""
The node's parameters in one table: names, defaults, units, ranges, and which may change live.

ROS-free (no rclpy), so the YAML test and the offline tools can read it. The node turns every
entry into a declared parameter with a ParameterDescriptor; ``settings_from`` validates a full set
of values (at start and for every runtime change) and returns the node settings and the mapper
configuration, or raises ValueError naming the parameter.

Three groups:

- the node's own parameters (frames, pose source, queueing, publishing, logging);
- ``incremental.<field>``: every IncrementalConfig field except ``smemsf``;
- ``smemsf.<field>``: every SMEMSFConfig field (0 stands for None: "estimate it").

The mapper's configuration is read-only at runtime: it shapes a map already built (sigma, the
merge and split thresholds), so changing it live would leave a map made under two
configurations. Such changes are refused by the read-only descriptor; restart the node (or
call ~/reset after a restart) to map with new values. Frames, the pose source, scan matching
and the queue size are read-only for the same reason. Everything about timing, publishing and
logging may change live.
"""

import ast
from dataclasses import dataclass, fields
import inspect
import math
import os
import textwrap

from .core.incremental import IncrementalConfig, RANGES as INCREMENTAL_RANGES
from .core.register import CHORD_KNOTS, DEFAULT_CHORD_KNOTS
from .core.smemsf import RANGES as SMEMSF_RANGES, SMEMSFConfig


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter."""

    name: str
    default: object
    """bool, int, float, str or a list of floats (the ROS parameter type follows)."""
    description: str
    lo: float = None
    """Smallest allowed value (inclusive), for numbers; also the descriptor's range."""
    hi: float = None
    """Largest allowed value (inclusive), for numbers."""
    runtime: bool = False
    """May change while the node runs (else the descriptor is read-only)."""
    choices: tuple = ()
    """Allowed values, for strings with a fixed set."""
    optional: bool = False
    """The setting may be None ("estimate it"); the node's parameter then stands for None
    with 0."""


NODE_NAME = 'polyline_mapper_node'
"""The node's name (its parameter file block, its logger)."""

NODE_PARAMS = (
    ParamSpec('fixed_frame', 'map',
              'Frame of the map and of everything published. In tf mode, poses of the scan '
              'frame are looked up in it; in odom mode it must be the odometry frame '
              '(nav_msgs/Odometry header.frame_id). With scan_matching the node owns this frame '
              'and broadcasts fixed_frame -> odometry frame; poses come from the odometry frame.'),
    ParamSpec('pose_source', 'tf',
              "Where scan poses come from: 'tf' (fixed_frame <- scan frame from /tf and "
              "/tf_static), 'odom' (nav_msgs/Odometry on 'odom' plus the laser_* mount) or "
              "'scan' (no pose data: each scan predicted at constant velocity and refined by "
              'scan matching, which this implies; the first scan at the origin of fixed_frame).',
              choices=('tf', 'odom', 'scan')),
    ParamSpec('scan_matching', False,
              'Localize as well as map: refine each scan pose (predicted from odometry or TF) '
              'against the map built so far, broadcast fixed_frame -> odometry frame (map -> '
              'odom) on /tf and the base pose on pose (PoseWithCovarianceStamped). Off: the '
              'poses are used as given (a robot with its own localizer). A map_input_path turns '
              'it on.'),
    ParamSpec('odom_frame', '',
              'scan_matching: the odometry frame, the child of the fixed_frame -> odom transform '
              "the node broadcasts. '' = found: the first odometry message's frame (odom mode) "
              "or the root of the scan frame's TF tree (tf mode). Set it when that root is not "
              'the odometry frame (e.g. robot1/odom on a multi-robot tree).'),
    ParamSpec('chord_knots', DEFAULT_CHORD_KNOTS,
              "scan_matching: where the knots of the last scans' chords (matched to beside the "
              "map) lie along each scan: 'median' every 0.15 m of an arc whose steps are each "
              "the median of 31 around it; 'arc' (the default before 2026-11-30) every 0.15 m "
              'of the arc through its readings, whose knots noise displaces along the sweep: '
              'every match then turns the same way (-0.1 deg a match on the Intel log; 1.9-4.9 '
              "deg over a 3-minute drive of a TurtleBot3's LDS-01).", choices=CHORD_KNOTS),
    ParamSpec('map_odom_post_date', 0.2,
              'scan_matching: seconds the map -> odom transform is stamped after its scan, as '
              "AMCL's transform_tolerance, so transforms at the current time resolve between "
              'two scans.', 0.0, 10.0, True),
    ParamSpec('transform_tolerance', 0.1,
              'Seconds a scan stamp may lie outside the stored transforms (or odometry) and '
              'still use the nearest one (held, never extrapolated).', 0.0, 10.0, True),
    ParamSpec('transform_timeout', 0.5,
              'Seconds a scan waits for a pose that may still come (no transforms yet, unknown '
              'frame, stamp newer than the newest transform) before it is skipped.',
              0.0, 10.0, True),
    ParamSpec('transform_cache', 30.0,
              'Seconds of transform (or odometry) history kept per frame.', 1.0, 3600.0),
    ParamSpec('laser_x', 0.0, 'odom mode: laser x in the odometry child (base) frame, metres.',
              -100.0, 100.0),
    ParamSpec('laser_y', 0.0, 'odom mode: laser y in the odometry child (base) frame, metres.',
              -100.0, 100.0),
    ParamSpec('laser_yaw', 0.0, 'odom mode: laser yaw in the odometry child (base) frame, rad.',
              -2 * math.pi, 2 * math.pi),
    ParamSpec('laser_upside_down', False,
              'odom mode: the laser is mounted upside down (rolled 180 deg): beams sweep '
              'clockwise seen from above.'),
    ParamSpec('odom_gap_factor', 1.5,
              'A scan stamped between two odometry messages (odom mode) or two transforms of '
              'the odometry edge (tf mode: the lowest moving transform above the laser, '
              'odom -> base_link) more than this many times the typical interval apart (a '
              'lost message; typical: the median of the last 51 intervals) is skipped instead '
              'of given a pose interpolated across motion nobody saw. 0 interpolates across '
              'any gap, as tf2 does.',
              0.0, 100.0),
    ParamSpec('scan_time_offset', 0.0,
              "Seconds added to every scan's stamp before it is posed, as a laser driver's "
              'time offset: -0.1 for a driver that stamps its scans 0.1 s late (when sent, '
              'not at the first beam). With scan matching the node estimates the lag from '
              'its matched turns and warns (scan_clock) with the value to set.',
              -10.0, 10.0),
    ParamSpec('scan_buffer_size', 50,
              'Scans that may wait for their pose and the next update; when updates fall '
              'behind, the oldest are dropped (and counted).', 1, 10000),
    ParamSpec('max_scan_latency', 1.0,
              'Seconds a posed scan may wait for its update; when updates are slower than the '
              'scans, older ones are dropped (and counted) so the map stays current. 0 turns '
              'this off (only scan_buffer_size bounds the queue).', 0.0, 3600.0, True),
    ParamSpec('update_every_n_scans', 1,
              'Run an incremental update once this many scans have their pose; their points '
              'go into one update. At most scan_buffer_size.', 1, 1000, True),
    ParamSpec('map_output_path', '~/.ros/polyline_map.json',
              'Where ~/save_map writes the map JSON (~ is expanded).', runtime=True),
    ParamSpec('save_map_on_shutdown', False,
              'Write the map to map_output_path when the node shuts down (SIGINT, SIGTERM), '
              'as ~/save_map does, after mapping the scans still queued; a file there is '
              'replaced.', runtime=True),
    ParamSpec('map_publish_period', 0.2,
              'Least seconds between two publications of polyline_map and its markers; 0 '
              'publishes after every update. A pending change is always published.',
              0.0, 3600.0, True),
    ParamSpec('publish_markers', True, 'Publish polyline_map/markers (MarkerArray).',
              runtime=True),
    ParamSpec('grid_resolution', 0.05,
              "Cell size (m) of the planner map on 'map' (nav_msgs/OccupancyGrid): occupied "
              'cells from the polylines, free cells from the traced beams, unknown elsewhere.',
              0.01, 10.0),
    ParamSpec('grid_publish_period', 1.0,
              "Least seconds between two publications of the planner map on 'map' (a pending "
              'change is always published); 0 turns the publication off (the grid is still '
              'kept, for ~/save_map).', 0.0, 3600.0, True),
    ParamSpec('marker_color', [0.1, 0.5, 1.0, 1.0], 'Marker colour: red, green, blue, alpha in '
              '[0, 1].', runtime=True),
    ParamSpec('marker_width', 0.05, 'Marker line width, metres.', 0.001, 10.0, True),
    ParamSpec('warning_period', 10.0,
              'Seconds between two warnings of the same cause (skipped scans); each warning '
              'counts the ones suppressed since the last.', 0.0, 3600.0, True),
    ParamSpec('stats_period', 30.0,
              'Seconds between two info lines with map size and update times; 0 turns them '
              'off.', 0.0, 3600.0, True),
    ParamSpec('diagnostics_period', 1.0,
              'Seconds between two diagnostic_msgs/DiagnosticArray on /diagnostics (counts, '
              'map size, update-time percentiles); 0 turns them off.', 0.0, 3600.0, True),
    ParamSpec('map_input_path', '',
              'A saved map (MAP.json of replay, fit or ~/save_map; ~ is expanded) to start from '
              "and localize on; '' starts with an empty map. Loading a map turns scan matching "
              'on: the scans are registered to it. A missing or unreadable map stops the node '
              'at start-up. ~/reset goes back to it.'),
    ParamSpec('initial_pose', [0.0, 0.0, 0.0],
              'With map_input_path: x, y, yaw (m, m, rad) of the robot (the frame the laser is '
              'mounted on) in the saved map at the first scan; default the map origin, where a '
              'map made from odometry started.'),
    ParamSpec('mapping', True,
              'true: map the scans (into the saved map of map_input_path, if any); false: keep '
              'the map fixed (localization only: the published and saved map is the loaded '
              'one, unchanged).'),
)

# Closed hulls of what IncrementalConfig / SMEMSFConfig accept (they check them, then the exact
# rules, naming the field); these ranges are what rqt and `ros2 param describe` show.
CORE_RANGES = {**{f'incremental.{k}': v for k, v in INCREMENTAL_RANGES.items()},
               **{f'smemsf.{k}': v for k, v in SMEMSF_RANGES.items()}}
CORE_CHOICES = {'smemsf.init': ('diagonals', 'single', 'random')}


def field_docs(cls) -> dict:
    """Return the attribute docstrings of a dataclass (the string after each field), by name."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError, SyntaxError):
        return {}
    body = tree.body[0].body
    out = {}
    for stmt, nxt in zip(body, body[1:]):
        if (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)
                and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)
                and isinstance(nxt.value.value, str)):
            out[stmt.target.id] = ' '.join(nxt.value.value.split())
    return out


def _core_specs(prefix: str, cls, skip=()) -> list:
    docs = field_docs(cls)
    defaults = cls()
    out = []
    for f in fields(cls):
        if f.name in skip:
            continue
        name = f'{prefix}.{f.name}'
        value = getattr(defaults, f.name)
        optional = value is None
        if optional:                   # "automatic": ROS parameters have no None
            value = 0.0
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise TypeError(f'{cls.__name__}.{f.name}: no ROS parameter type for {value!r}')
        lo, hi = CORE_RANGES.get(name, (None, None))
        doc = docs.get(f.name, f'{cls.__name__}.{f.name}')
        out.append(ParamSpec(name, value, doc, lo, hi, False, CORE_CHOICES.get(name, ()),
                             optional))
    return out


def all_params() -> tuple:
    """Return every parameter the node declares: its own, incremental.*, smemsf.*."""
    return (NODE_PARAMS + tuple(_core_specs('incremental', IncrementalConfig, skip=('smemsf',)))
            + tuple(_core_specs('smemsf', SMEMSFConfig)))


ROS_OWN_PARAMS = ('use_sim_time', 'start_type_description_service')
"""Parameters rclpy declares on every node."""


def unknown_params(names) -> list:
    """
    Return the names among ``names`` that are no parameter of the node, each with a hint.

    rcl keeps a ``-p`` or params-file value for a name the node never declares without a
    word, so a misspelt ``scan_matchng`` or fit's short ``sigma`` (the node's ``smemsf.sigma``)
    is silently not used. Each as 'name' or 'name (did you mean X?)'; ``qos_overrides.*`` and
    rclpy's own parameters are known.
    """
    import difflib
    known = [spec.name for spec in all_params()]
    out = []
    for name in sorted(set(names)):
        if name in known or name in ROS_OWN_PARAMS or name.startswith('qos_overrides.'):
            continue
        near = [k for k in known if k.rpartition('.')[2] == name] or \
            difflib.get_close_matches(name, known, n=1)
        out.append(f'{name} (did you mean {near[0]}?)' if near else name)
    return out


def defaults() -> dict:
    """Return {name: default} of every declared parameter."""
    return {p.name: p.default for p in all_params()}


@dataclass(frozen=True)
class NodeSettings:
    """The node's own parameters, validated (see NODE_PARAMS for meanings and units)."""

    fixed_frame: str
    pose_source: str
    scan_matching: bool
    odom_frame: str
    chord_knots: str
    map_odom_post_date: float
    transform_tolerance: float
    transform_timeout: float
    transform_cache: float
    laser_x: float
    laser_y: float
    laser_yaw: float
    laser_upside_down: bool
    odom_gap_factor: float
    scan_time_offset: float
    scan_buffer_size: int
    max_scan_latency: float
    update_every_n_scans: int
    map_output_path: str
    save_map_on_shutdown: bool
    map_publish_period: float
    publish_markers: bool
    grid_resolution: float
    grid_publish_period: float
    marker_color: tuple
    marker_width: float
    warning_period: float
    stats_period: float
    diagnostics_period: float
    map_input_path: str
    initial_pose: tuple
    mapping: bool

    @property
    def output_path(self) -> str:
        """Return map_output_path with ~ expanded."""
        return os.path.expanduser(self.map_output_path)

    @property
    def input_path(self) -> str:
        """Return map_input_path with ~ expanded ('' for none)."""
        return os.path.expanduser(self.map_input_path) if self.map_input_path else ''


def check_value(spec: ParamSpec, value) -> None:
    """Raise ValueError naming the parameter when ``value`` breaks its type, range or choices."""
    d = spec.default
    if isinstance(d, bool):
        ok = isinstance(value, bool)
    elif isinstance(d, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(d, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif isinstance(d, str):
        ok = isinstance(value, str)
    else:
        ok = hasattr(value, '__len__') and not isinstance(value, (str, bytes)) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    if not ok:
        raise ValueError(f'{spec.name} must be of type {type(d).__name__}, got {value!r}')
    if isinstance(d, (int, float)) and not isinstance(d, bool):
        if not math.isfinite(value):
            raise ValueError(f'{spec.name} must be finite, got {value!r}')
        if (spec.lo is not None and value < spec.lo) or (spec.hi is not None and value > spec.hi):
            raise ValueError(f'{spec.name} must be in [{spec.lo:g}, {spec.hi:g}], got {value!r}')
    if spec.choices and value not in spec.choices:
        raise ValueError(f'{spec.name} must be one of {", ".join(spec.choices)}, got {value!r}')


def settings_from(values: dict) -> tuple:
    """
    Validate a full set of parameter values; return (NodeSettings, IncrementalConfig).

    Raises ValueError with a one-line reason naming the parameter.
    """
    specs = {p.name: p for p in all_params()}
    unknown = sorted(set(values) - set(specs))
    if unknown:
        raise ValueError(f'unknown parameter(s): {", ".join(unknown)}')
    missing = sorted(set(specs) - set(values))
    if missing:
        raise ValueError(f'missing parameter(s): {", ".join(missing)}')
    for name, value in values.items():
        check_value(specs[name], value)
    node = {p.name: values[p.name] for p in NODE_PARAMS}
    if not node['fixed_frame'].strip():
        raise ValueError('fixed_frame must not be empty: it must be a frame name (e.g. map)')
    if not node['map_output_path'].strip():
        raise ValueError('map_output_path must not be empty')
    if node['fixed_frame'].lstrip('/') != node['fixed_frame']:
        raise ValueError(f"fixed_frame must not start with '/', got {node['fixed_frame']!r}")
    odom = node['odom_frame'].strip()
    if odom.lstrip('/') != odom:
        raise ValueError(f"odom_frame must not start with '/', got {node['odom_frame']!r}")
    if odom == node['fixed_frame']:
        raise ValueError(f'odom_frame must differ from fixed_frame ({odom!r}): the node '
                         'broadcasts fixed_frame -> odom_frame')
    node['odom_frame'] = odom
    color = tuple(float(c) for c in node['marker_color'])
    if len(color) != 4 or not all(0.0 <= c <= 1.0 for c in color):
        raise ValueError(f'marker_color must be 4 numbers in [0, 1] (r, g, b, a), got {color}')
    node['marker_color'] = color
    pose = tuple(float(v) for v in node['initial_pose'])
    if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
        raise ValueError(f'initial_pose must be 3 finite numbers (x, y, yaw: m, m, rad), got '
                         f'{list(pose)}')
    node['initial_pose'] = pose
    if node['pose_source'] == 'scan':
        # Scans alone are placed by matching them (the session's scan mode implies it): the
        # node then publishes the pose and takes pose estimates on initialpose, which a lost
        # track waits for (without them, the matched poses were unseen and a lost node could
        # not be placed again).
        node['scan_matching'] = True
    if node['map_input_path'].strip():
        # Localizing on a saved map is matching to it: the node is then the localizer and
        # broadcasts map -> odom and the pose (without them it localized, unseen, or, with
        # fixed_frame map, skipped every scan: 'map' unknown).
        node['scan_matching'] = True
    else:
        # As replay's --no-mapping / --initial-pose without --map: nothing to keep or place.
        if not node['mapping']:
            raise ValueError('mapping false keeps a saved map fixed: give map_input_path (without '
                             'one nothing would ever be mapped)')
        if any(pose):
            raise ValueError(f'initial_pose {list(pose)} places the robot in a saved map: give '
                             'map_input_path (or leave initial_pose at [0.0, 0.0, 0.0])')
    if node['update_every_n_scans'] > node['scan_buffer_size']:
        raise ValueError(f"update_every_n_scans ({node['update_every_n_scans']}) must be at most "
                         f"scan_buffer_size ({node['scan_buffer_size']})")
    for name in ('map_odom_post_date', 'transform_tolerance', 'transform_timeout',
                 'transform_cache', 'max_scan_latency', 'laser_x', 'laser_y', 'laser_yaw',
                 'odom_gap_factor', 'scan_time_offset',
                 'map_publish_period', 'marker_width', 'warning_period', 'stats_period',
                 'grid_resolution', 'grid_publish_period'):
        node[name] = float(node[name])
    return NodeSettings(**node), mapper_config(values)


def mapper_config(values: dict) -> IncrementalConfig:
    """
    Return the IncrementalConfig of parameter values (``smemsf.*``, ``incremental.*``).

    Other names are ignored; a missing one keeps its default. Raises ValueError with a
    one-line reason naming the parameter.
    """
    smemsf = {k.split('.', 1)[1]: v for k, v in values.items() if k.startswith('smemsf.')}
    inc = {k.split('.', 1)[1]: v for k, v in values.items() if k.startswith('incremental.')}
    try:
        return IncrementalConfig(smemsf=SMEMSFConfig.from_dict(smemsf), **inc)
    except ValueError as exc:
        group = 'incremental' if any(str(exc).startswith(k) for k in inc) else 'smemsf'
        raise ValueError(f'{group}.{exc}') from None
    except TypeError as exc:
        raise ValueError(f'bad mapper configuration: {exc}') from None
