"""
``polyline-mapper``: the command line, a thin shell over the core.

Subcommands:
  fit INPUT -o MAP.json [--plot MAP.png] [--config FILE]   fit a map to points, a log or a bag
  demo -o MAP.json [--plot MAP.png] [--offline]             live node + simulated office drive
  replay INPUT -o MAP.json [--plot MAP.png] ...             map a bag or CARMEN log scan by scan
         [--map SAVED.json [--initial-pose X,Y,YAW_DEG] [--no-mapping]]  ... on a saved map
  plot MAP.json [--points INPUT [--free-space]] -o MAP.png  draw a map (over points or beams)
  export MAP.json -o OUT.{geojson,svg,csv,yaml}             convert a map for other tools
  export MAP.json --trajectory -o OUT.{csv,tum}            its trajectory (replay's poses)
  convert LOG -o BAG [--storage sqlite3|mcap]               CARMEN log -> rosbag2
  play INPUT [--rate R] [--loop]                            publish a recording on live topics
  record-map [TOPIC] -o MAP.json [--plot MAP.png]           save the map a running node publishes

Errors in input, files or configuration end the program with exit code 2 and one line saying
why; no output file is left behind by a failed run. Every output goes through
``formats.output``: never over an input, a device, a folder or a read-only file; a symlink is
followed to its target; a replaced file keeps its mode; a map JSON and its PNG are written all or
nothing. Outputs are checked before the work starts, so a bad ``-o`` fails at once.

Maps are judged two ways in the stats of fit and replay: the distance of the points to the map,
and, when the input has beams (CARMEN logs, bags, simulated drives), the share of map length
the beams pass through (``core.freespace``); a bare point file says "no beams".
"""

import argparse
import dataclasses
import io
import math
import os
import re
import signal
import sys
import time

import numpy as np

from .core import fit, map_metrics, SMEMSFConfig
from .core.incremental import COORD_LIMIT
from .core.mapvalue import MapValue
from .formats.mapjson import config_dict, dumps_map, map_value_to_dict
from .formats.output import check_outputs, OutputSet
from .formats.points import MAX_COORDINATE

EXIT_USAGE = 2


class CliError(Exception):
    """An error to report as one line with exit code 2."""


def load_config(path: str = None, overrides: list = ()) -> SMEMSFConfig:
    """Return the fit configuration of ``--config`` and ``--set`` (see ``config``)."""
    from .config import load_fit_config
    return load_fit_config(path, overrides)


def load_fit_options(path: str = None, overrides: list = ()) -> tuple:
    """Return (fit configuration, free-space keywords of ``fit``) of ``--config`` and ``--set``."""
    from .config import load_fit_options as load
    return load(path, overrides)


def fit_window_asked(path: str = None, overrides: list = ()) -> bool:
    """
    Whether ``--config`` or ``--set`` gives ``free_space_window`` (not only the default).

    -1 (the shipped config/polyline_mapper.yaml's value) is the default itself: 'by the pose
    source', which a point file resolves to 0 without a word.
    """
    from .config import FIT_EXTRA, read_values
    window = read_values(path, overrides, ('smemsf',), FIT_EXTRA).get('free_space_window')
    return window is not None and window != -1


def load_incremental_config(path: str = None, overrides: list = (), also=()):
    """
    Return the mapper configuration of ``--config`` and ``--set`` (see ``config``).

    ``also``: the node parameters ``--set`` takes besides (named with the mapper's keys when a
    key is unknown).
    """
    from .config import load_mapper_config
    return load_mapper_config(path, overrides, also)


def read_input(path: str, range_max: float = None, progress: bool = True) -> tuple:
    """
    Read an (N, 2) point file or a CARMEN log; return points, origins and a description.

    ``origins`` (N, 2) are the laser positions of a log's points, None for a point file.
    """
    from .recordings import read_beams
    return read_beams(path, range_max, _progress_factory(progress, 'register', 'scan'),
                      warn=lambda line: print(f'polyline-mapper: warning: {line}',
                                              file=sys.stderr))


def _progress_factory(enabled: bool, desc: str, unit: str):
    if not enabled:
        return None
    from tqdm import tqdm

    def wrap(items):
        return tqdm(items, desc=desc, unit=unit, leave=False, disable=None, file=sys.stderr)
    return wrap


def run_fit(points: np.ndarray, config: SMEMSFConfig, progress: bool = True, origins=None,
            free_space_window: int = 0, free_space_hit_margin: float = 0.0):
    """
    Fit with a progress bar over iterations (shown on a terminal only).

    ``origins`` (N, 2) and ``free_space_window`` > 0: fit with the beams' free-space evidence
    (and ``free_space_hit_margin``); ``origins`` and ``config.range_noise``: the ranges give
    the points their noise scales (with the window 0, without the evidence).
    """
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=int(config.max_iterations), desc='SMEMSF', unit='it', leave=False,
                   disable=None, file=sys.stderr)

    def tick(it, info):
        if bar is not None:
            bar.update(1)
            bar.set_postfix(segments=info['segments'], sigma=f"{info['sigma'] * 100:.1f}cm")
    try:
        if origins is None or (free_space_window <= 0 and not config.range_noise):
            return fit(points, config, progress=tick)
        return fit(points, config, progress=tick, origins=origins,
                   free_space_window=max(int(free_space_window), 0),
                   free_space_hit_margin=free_space_hit_margin)
    finally:
        if bar is not None:
            bar.close()


def write_outputs(result, points, config, out_json: str, out_png: str = None,
                  frame_id: str = 'map', title: str = '', truth=None, extra=None,
                  inputs=(), origins=None) -> dict:
    """
    Write the map JSON (and PNG) of a batch fit, all or nothing; return the stats written.

    ``origins`` (N, 2): the laser position of each point (free space is judged), or None.
    """
    from .core.freespace import free_space_stats
    stats = map_metrics(points, result.segments)
    stats.update(free_space_stats(result.segments, points, origins))
    stats.update(iterations=int(result.iterations), converged=bool(result.converged),
                 seconds=round(float(result.seconds), 3), polylines=len(result.polylines),
                 sigma=float(result.sigma), r=float(result.r))
    stats.update(extra or {})
    value = MapValue.from_fit(result, frame_id, stats)
    save_map(value, points, out_json, out_png, title, truth, config=config.to_dict(),
             inputs=inputs)
    return stats


def save_map(data, points, out_json: str = None, out_png: str = None, title: str = '',
             truth=None, config: dict = None, inputs=(), grid=None) -> None:
    """
    Write a map as JSON and/or a PNG over its points, together and all or nothing.

    ``data``: a MapValue (written with ``config`` and the planner map ``grid``, if given) or a
    map dict (``map_to_dict``). Both
    outputs are checked (``formats.output``) against ``inputs`` and each other before the PNG
    is drawn; neither file exists unless both were written.
    """
    if isinstance(data, MapValue):
        segs, polys = data.segments, data.polylines
        data = map_value_to_dict(data, config, grid)
    else:
        segs = np.asarray(data['segments'], dtype=float).reshape(-1, 2, 2)
        polys = [np.asarray(p, dtype=float).reshape(-1, 2) for p in data['polylines']]
    with OutputSet(inputs) as out:
        out.add(out_json)
        out.add(out_png)
        text = dumps_map(data) if out_json else None      # NaN / inf: ValueError, nothing written
        if out_png:
            from .plot import plot_map
            png = io.BytesIO()
            plot_map(png, np.zeros((0, 2)) if points is None else points, segs, polys,
                     title=title, truth=truth)
            out.put(out_png, png.getvalue())
        if out_json:
            out.put(out_json, text)


def no_segment_reason(n_points: int, config: SMEMSFConfig, sigma: float,
                      spacing: float = None) -> str:
    """
    Say why a batch fit of ``n_points`` valid points found no segment.

    ``spacing``: the points' median nearest-neighbour distance (m); wider than a square (2r)
    at the final ``sigma``, the density test cannot pass, and the reason names the noise scale
    that would let it (points 1 m apart along walls gave no segment and no hint why).
    """
    if n_points < config.min_support:
        return (f'{n_points} points are fewer than min_support ({config.min_support:g}), the '
                'least a segment needs')
    reason = (f'no structure: every candidate segment in the {n_points} points fell below '
              f'min_support ({config.min_support:g} points) or min_density '
              f'({config.min_density:g} per 2r) at sigma {sigma * 100:.2f} cm')
    two_r = 2.0 * config.r_over_sigma * sigma
    if spacing is not None and spacing > two_r:
        least = spacing / (2.0 * config.r_over_sigma)         # 2r = the spacing
        step = 10.0 ** np.floor(np.log10(least))
        need = float(f'{np.ceil(least / step * (1 - 1e-12)) * step:.1g}')   # one digit, up
        reason += (f'; the points lie a median {spacing:.3g} m apart, wider than 2r '
                   f'({two_r * 100:.2f} cm): if they sample walls that sparsely, give their '
                   f'noise scale, e.g. --set sigma={need:g}')
    return reason


def median_spacing(points: np.ndarray) -> float:
    """Median distance from a point to its nearest other point (m); nan for fewer than 2."""
    if len(points) < 2:
        return float('nan')
    from scipy.spatial import cKDTree
    d, _ = cKDTree(points).query(points, k=2)
    return float(np.median(d[:, 1]))


def summary_line(path: str, stats: dict, plot: str = None) -> str:
    """One line a person reads after a run (``plot``: the PNG written beside ``path``)."""
    path = f'{path} and {plot}' if plot else path
    if not stats['segments']:
        return (f"wrote {path}: an empty map (0 segments) from {stats['points']} points, "
                f"{stats['iterations']} iterations, {stats['seconds']:.1f} s")
    return (f"wrote {path}: {stats['segments']} segments in {stats['polylines']} polylines from "
            f"{stats['points']} points, mean distance {stats['mean_distance'] * 100:.2f} cm, "
            f"p95 {stats['p95_distance'] * 100:.2f} cm, coverage "
            f"{stats['coverage_0_10m'] * 100:.1f}%{free_space_text(stats)}, "
            f"{stats['iterations']} iterations, {stats['seconds']:.1f} s"
            + (f", free-space evidence of {stats['free_space_beams']} beams cut "
               f"{stats['free_squares']} squares" if stats.get('free_space_beams') else ''))


def free_space_text(stats: dict) -> str:
    """Return the contradicted share for a summary line (or 'no beams: free space not judged')."""
    from .replay import free_space_text as text
    return text(stats)


def _warn_if_empty(source: str, stats: dict, config: SMEMSFConfig, points: np.ndarray) -> None:
    if not stats['segments']:
        reason = no_segment_reason(stats['points'], config, stats['sigma'],
                                   median_spacing(points))
        print(f'polyline-mapper: warning: {source}: no segment found ({reason}); wrote an '
              'empty map', file=sys.stderr)


_FORMATS = ('.json', '.png', '.jpg', '.jpeg', '.svg', '.pdf', '.geojson', '.csv', '.yaml', '.yml',
            '.pgm', '.tum', '.txt', '.npy', '.log', '.gz', '.db3', '.mcap', '.bag')
"""Suffixes that name a file format: an output named so must be of it."""


def _suffixes(map_json: str = None, png: str = None) -> None:
    """
    Refuse an output whose name says another format than the file it would get (CliError).

    A map is JSON, a plot PNG; a name without a suffix, or with one that names no format
    (``map.out``), is taken as given.
    """
    for path, want, what in ((map_json, '.json', 'the map is written as JSON'),
                             (png, '.png', 'the plot is a PNG image')):
        ext = None if path is None else os.path.splitext(path)[1].lower()
        if ext in _FORMATS and ext != want:
            more = (' (polyline-mapper export writes GeoJSON, SVG, CSV, the map_server YAML '
                    'and trajectories)' if want == '.json' else '')
            raise CliError(f'{path}: {what}, not {ext}: give a name ending in {want}{more}')


def _fit_node_warnings(path: str) -> list:
    """
    Return ``fit``'s warnings on a ROS 2 parameter file's node parameters: it uses none.

    fit places a bag's or a drive's scans by its own flags (``--pose-source``, ...); the
    parameters replay would take, the live node's own, names the node does not have, and a
    value the node would refuse are each named.
    """
    from .config import ConfigError, read_node_file, REPLAY_READS
    if not path:
        return []
    try:
        nf = read_node_file(path)
    except ConfigError as exc:
        return [f'{exc} (fit does not use the node parameters)']
    out = []
    placed = [n for n in nf.names if n in REPLAY_READS]
    if placed:
        out.append(f'{path}: node parameters not used by fit (it places scans by its own '
                   f'flags: --pose-source, --laser-mount, ...; replay --config takes them): '
                   f'{", ".join(placed)}')
    return out + _node_file_warnings(nf, path, 'fit')


def cmd_fit(args) -> int:
    inputs = [args.input, args.config]
    check_outputs([args.output, args.plot], inputs)
    _suffixes(args.output, args.plot)
    config, extra = load_fit_options(args.config, args.set)
    window = extra['free_space_window']
    for line in _fit_node_warnings(args.config):
        print(f'polyline-mapper: warning: {line}', file=sys.stderr)
    t0 = time.perf_counter()
    points, origins, desc, posed = read_beams_any(args.input, args, args.range_max)
    if len(points) < 2:
        raise CliError(f'{args.input}: {len(points)} usable point(s); need at least 2')
    if window > 0 and origins is None and fit_window_asked(args.config, args.set):
        print(f'polyline-mapper: warning: {args.input}: free_space_window={window} cannot be '
              'applied: a point file has no beams (laser positions); fitting the bare points',
              file=sys.stderr)
    if config.range_noise and origins is None:
        print(f'polyline-mapper: warning: {args.input}: range_noise={config.range_noise:g} '
              'cannot be applied: a point file has no ranges (laser positions); fitting at '
              'one noise scale (stored as range_noise 0)', file=sys.stderr)
        config = dataclasses.replace(config, range_noise=0.0)
    result = run_fit(points, config, not args.quiet, origins, **extra)
    used = window if result.beams else 0
    # A bag's or a drive's scans are registered in the replay's fixed frame (the TF tree's
    # root, 'odom' without a map frame; the odometry frame with --pose-source odom): label
    # the map with it unless --frame-id says otherwise.
    frame_id = args.frame_id or posed.get('fixed_frame') or 'map'
    stats = write_outputs(result, points, config, args.output, args.plot, frame_id,
                          title=f'{os.path.basename(args.input)}: {len(result.segments)} segments',
                          extra={'input': os.path.basename(os.path.normpath(args.input)),
                                 'input_type': desc, **posed,
                                 'total_seconds': round(time.perf_counter() - t0, 3),
                                 'free_space_window': used, 'free_space_hit_margin':
                                     extra['free_space_hit_margin'] if used else 0.0,
                                 'free_space_beams': result.beams,
                                 'free_squares': result.free_squares},
                          inputs=inputs, origins=origins)
    _warn_if_empty(args.input, stats, config, points)
    if origins is not None:
        disagree = _seen_through(stats, args, config.range_noise)
        if disagree:
            print(f'polyline-mapper: warning: {disagree}', file=sys.stderr)
    elif stats['segments'] and stats['coverage_0_10m'] < 0.5:
        # Bare points (no poses to blame): 3000 uniform random points gave 14 segments
        # covering 18 % of them, without a word (new-user audit). Most of them: a room's walls
        # with 8 cm range noise are covered 80 % within 0.10 m, and rightly fitted.
        off = (1 - stats['coverage_0_10m']) * 100
        print(f'polyline-mapper: warning: {args.input}: the map leaves '
              f'{off:.0f}% of the points more than 0.10 m off: '
              'most of them do not lie along lines (scattered points, noise)', file=sys.stderr)
    if not args.quiet:
        print(summary_line(args.output, stats, args.plot))
    return 0


def cmd_demo(args) -> int:
    if not args.offline:
        return cmd_live_demo(args)
    live = [flag for flag, given in (('--rate', args.rate != 1.0),
                                     ('--domain-id', args.domain_id is not None)) if given]
    if live:
        print(f'polyline-mapper: warning: {" and ".join(live)} appl'
              f'{"ies" if len(live) == 1 else "y"} to the live demo only, not with --offline',
              file=sys.stderr)
    from .sim import LaserSpec, office_floor, simulate_drive
    check_outputs([args.output, args.plot], [args.config])
    _suffixes(args.output, args.plot)
    config = load_config(args.config, args.set)
    world = office_floor()
    drive = simulate_drive(world, LaserSpec(noise=args.noise), rng=args.seed)
    from .recordings import drive_beams
    points, origins = drive_beams(drive)
    result = run_fit(points, config, not args.quiet)
    stats = write_outputs(result, points, config, args.output, args.plot, 'map',
                          title=f'simulated office floor: {len(result.segments)} segments',
                          truth=world.walls, extra={'input': 'simulated office floor',
                                                    'scans': int(len(drive.poses))},
                          inputs=[args.config], origins=origins)
    _warn_if_empty('simulated office floor', stats, config, points)
    if not args.quiet:
        print(summary_line(args.output, stats, args.plot))
    return 0


def demo_params(items) -> dict:
    """
    Return the live demo's ``--set KEY=VALUE`` items as node parameters {name: text}.

    fit's and replay's short keys (``sigma``) name the node's ``smemsf.*`` / ``incremental.*``
    ones; a key the node does not have is refused (passed on as ``-p``, rcl would keep it
    unused).
    """
    from .params import all_params, unknown_params
    names = [spec.name for spec in all_params()]
    params = {}
    for item in items:
        key, sep, value = item.partition('=')
        key = key.strip()
        if not sep or not key:
            raise CliError(f'--set expects KEY=VALUE (a node parameter), got {item!r}')
        if unknown_params([key]):           # (qos_overrides.* and rclpy's own are known)
            full = [name for name in names if name.rpartition('.')[2] == key]
            if len(full) != 1:
                raise CliError(f'--set {item}: the node has no parameter '
                               f'{unknown_params([key])[0]} (config/polyline_mapper.yaml '
                               'lists them)')
            key = full[0]
        params[key] = value.strip()
    return params


def cmd_live_demo(args) -> int:
    from .ros.live_demo import DemoError, run_live_demo
    check_outputs([args.output, args.plot], [args.config])
    _suffixes(args.output, args.plot)
    params = demo_params(args.set)
    try:
        res = run_live_demo('sim:office', rate=args.rate, seed=args.seed, noise=args.noise,
                            params=params, params_file=args.config,
                            domain_id=args.domain_id, progress=not args.quiet)
    except DemoError as exc:
        raise CliError(f'live demo failed: {exc}') from None
    st = res.value.stats
    title = (f"simulated office, live node: {st['segments']} segments, mean distance "
             f"{100 * st['mean_distance']:.2f} cm")
    save_map(res.value, res.points, args.output, args.plot, title=title, truth=res.walls,
             inputs=[args.config], grid=res.grid, config=res.config)
    if not args.quiet:
        print(f"wrote {args.output}{' and ' + args.plot if args.plot else ''}: "
              f"{st['segments']} segments from {st['scans_used']} of {st['scans']} scans, "
              f"mean distance {100 * st['mean_distance']:.2f} cm, coverage "
              f"{100 * st['coverage_0_10m']:.1f}%, node update median "
              f"{st['update_ms_median']:.1f} ms (p99 {st['update_ms_p99']:.1f} ms), "
              f"{st['play_seconds']:.0f} s drive")
    return 0


def _ros_args(args) -> list:
    """Return ``--ros-args ...`` given after the options (for remapping, domain, logging)."""
    return (['--ros-args'] + list(args.ros_args)) if args.ros_args else None


def cmd_play(args) -> int:
    from .ros.player import run_play
    stats = run_play(args.input, rate=args.rate, loop=args.loop, clock=not args.no_clock,
                     clock_hz=args.clock_hz, scan_topic=args.scan_topic,
                     odom_topic=args.odom_topic, wait_for_subscriber=args.wait_for_subscriber,
                     progress=not args.quiet, seed=args.seed, noise=args.noise,
                     period=args.period, ros_args=_ros_args(args),
                     log=lambda text: print(f'polyline-mapper: {text}', file=sys.stderr))
    if not args.quiet:
        print(stats.summary())
    if stats.interrupted:        # the shell's convention: 128 + signal (130 Ctrl-C, 143 TERM)
        return 128 + int(stats.stop_signal or signal.SIGINT)
    return 0


def cmd_record_map(args) -> int:
    from .ros.player import stop_on_signals
    from .ros.recorder import run_record_map
    check_outputs([args.output, args.plot])
    _suffixes(args.output, args.plot)
    stops = []
    # SIGINT and SIGTERM (docker stop, systemd, launch) end the recording: the newest map is
    # written and the exit code is 0 (the map was saved as asked; a signal is how an open-ended
    # recording ends, unlike `play`, which exits 128 + signal because it did not finish). A
    # second signal while the map is being written aborts it: exit 130, nothing written.
    with stop_on_signals(stops.append):
        value, grid, config, no_config, noise = run_record_map(
            args.topic, once=args.once, idle=args.idle, timeout=args.timeout,
            ros_args=_ros_args(args), should_stop=lambda: bool(stops),
            grid_topic=args.grid_topic)
        st = value.stats
        save_map(value, None, args.output, args.plot, grid=grid, config=config,
                 title=f"{st['segments']} segments from {st['topic']}")
    if st.get('scans_dropped'):
        print(f"polyline-mapper: warning: the node dropped {st['scans_dropped']} of the "
              f"{st['scans_received']} scans it received (it could not map them within its "
              'max_scan_latency: a recording played much faster than it was recorded); '
              f'{args.output} lacks them: play slower, or `replay` the recording, which maps '
              'every scan', file=sys.stderr)
    if config is None:
        print(f'polyline-mapper: warning: {args.output} has no config block (the mapper '
              f'settings the map was made with): {no_config}', file=sys.stderr)
    if noise is None:
        print(f'polyline-mapper: warning: {args.output} has no noise scale (stats.sigma: the '
              "publisher's /diagnostics did not report one): localizing on it needs one, "
              "replay --set sigma=M or the node's smemsf.sigma", file=sys.stderr)
    if args.grid_topic != '' and grid is None and st.get('grid_shared_with'):
        print(f"polyline-mapper: warning: {args.output} has no grid: {st['grid_topic']} is "
              f"also published by {', '.join(st['grid_shared_with'])} (the node does not "
              "publish its grid beside another map publisher): remap the node's grid (-r "
              'map:=polyline_map/grid) and pass --grid-topic polyline_map/grid',
              file=sys.stderr)
    elif args.grid_topic != '' and grid is None:
        print(f'polyline-mapper: warning: no planner map (nav_msgs/OccupancyGrid) of frame '
              f"{value.frame_id} on {st['grid_topic']}: {args.output} has no grid, so `export` "
              "marks the segments occupied and leaves the rest unknown (is the node's "
              'grid_publish_period 0, or its grid on another topic? --grid-topic names it)',
              file=sys.stderr)
    if not args.quiet:
        how = f', stopped by {signal.Signals(stops[0]).name}' if stops else ''
        with_grid = '' if grid is None else (f', with its planner map ({grid.width} x '
                                             f'{grid.height} cells, stamp '
                                             f"{st['grid_stamp']:.3f} s)")
        print(f"wrote {args.output}: {st['segments']} segments in {st['polylines']} polylines "
              f"(frame {value.frame_id}, stamp {st['stamp']:.3f} s) from {st['topic']}, "
              f"{st['maps_received']} map(s) received{with_grid}{how}")
    return 0


def _frame(text: str) -> str:
    """Parse a frame name: not empty, no leading '/', as the node's frames (argparse type)."""
    if not text.strip():
        raise argparse.ArgumentTypeError('must name a frame, got an empty string')
    if text.startswith('/'):
        raise argparse.ArgumentTypeError(f"must not start with '/' (tf2 refuses such frame "
                                         f"names), got {text!r}: give {text.lstrip('/')!r}")
    return text


XY_YAW_BOUNDS = '|X|, |Y| <= 1e6, |YAW_DEG| <= 360'
"""What --laser-mount takes: a yaw of 1e300 degrees ran to the end (its radians meaningless
after the wrap) with only a warning that the scans disagree."""
POSE_BOUNDS = f'|X|, |Y| <= {MAX_COORDINATE:g}, |YAW_DEG| <= 360'
"""What --initial-pose takes: anywhere a map file's coordinates may lie (a map in UTM
coordinates, northings about 5e6 m, could not be given a start before, an audit)."""


def _check_xy_yaw(x: float, y: float, yaw_deg: float, limit: float = 1e6) -> None:
    """Raise ValueError unless x, y (m) and yaw (deg) are finite and within the bounds."""
    if not (np.isfinite([x, y, yaw_deg]).all() and max(abs(x), abs(y)) <= limit
            and abs(yaw_deg) <= 360.0):
        raise ValueError


def _mount(text: str) -> tuple:
    """Parse ``X,Y,YAW_DEG[,flip]`` into ((x, y, yaw rad) or None, upside_down)."""
    if text is None:
        return None, False
    parts = [v.strip() for v in text.split(',')]
    flip = len(parts) == 4 and parts[3].lower() in ('flip', 'upside_down', 'upside-down')
    try:
        if len(parts) != (4 if flip else 3):
            raise ValueError
        x, y, yaw = (float(v) for v in parts[:3])
        _check_xy_yaw(x, y, yaw)
    except ValueError:
        raise CliError('--laser-mount expects X,Y,YAW_DEG or X,Y,YAW_DEG,flip (metres, '
                       f'degrees; {XY_YAW_BOUNDS}), got {text!r}') from None
    return (x, y, float(np.deg2rad(yaw))), flip


def _replay_options(args, every: int = 1, group: int = 1, matching: bool = False):
    from .session import SessionOptions
    given = [flag for flag, value in (('--odom-topic', args.odom_topic),
                                      ('--laser-mount', args.laser_mount)) if value is not None]
    if given and args.pose_source != 'odom':
        # Only the odometry pose source reads them: with tf the laser's mount comes from
        # /tf_static and odometry is not read, in scan mode no pose data at all.
        raise CliError(f'{" and ".join(given)} {"applies" if len(given) == 1 else "apply"} '
                       f'with --pose-source odom only (given: {args.pose_source})')
    knots = getattr(args, 'chord_knots', None)
    if knots is not None and not matching and args.pose_source != 'scan':
        # (fit and plot have no --scan-matching: they match scans in scan mode only)
        add = ('--scan-matching (or --pose-source scan)' if hasattr(args, 'scan_matching')
               else '--pose-source scan')
        raise CliError(f'--chord-knots applies to scan matching only: add {add}')
    mount, flip = _mount(args.laser_mount)
    source = args.pose_source or 'tf'           # (replay: None until _node_file)
    fixed = args.fixed_frame
    if fixed is None and matching and source == 'odom':
        # The matched map is not the odometry frame (it leaves it as the odometry drifts): it is
        # 'map', above the odometry frame, as the node's (REP 105).
        fixed = 'map'
    extra = dict(getattr(args, 'session_extra', None) or {})   # replay --config (_node_file)
    if getattr(args, 'scan_time_offset', None) is not None:
        extra['scan_time_offset'] = args.scan_time_offset         # the flag wins
    if 'mount' in extra:
        mount, flip = extra.pop('mount'), extra.pop('mount_upside_down')
    return SessionOptions(pose_source=source, fixed_frame=fixed,
                          every=every, update_every_n_scans=group, mount=mount,
                          mount_upside_down=flip, scan_matching=matching,
                          chord_knots=knots or SessionOptions.chord_knots, **extra)


def _initial_pose(text: str) -> tuple:
    """Parse ``X,Y,YAW_DEG`` into (x, y, yaw rad)."""
    parts = text.split(',')
    try:
        if len(parts) != 3:
            raise ValueError
        x, y, yaw = (float(v) for v in parts)
        _check_xy_yaw(x, y, yaw, MAX_COORDINATE)
    except ValueError:
        raise CliError('--initial-pose expects X,Y,YAW_DEG (metres, metres, degrees: the '
                       f'robot in the map at the first scan; {POSE_BOUNDS}), got {text!r}'
                       ) from None
    return x, y, float(np.deg2rad(yaw))


def _start_map(args) -> tuple:
    """Return (MapFile or None, initial pose or None) of --map, --initial-pose, --no-mapping."""
    if args.map is None:
        for flag, given in (('--no-mapping', args.no_mapping),
                            ('--initial-pose', args.initial_pose is not None)):
            if given:
                raise CliError(f'{flag} applies to a saved map: give --map MAP.json')
        return None, None
    from .formats.mapjson import read_map
    pose = getattr(args, 'file_initial_pose', None) if args.initial_pose is None \
        else _initial_pose(args.initial_pose)
    if args.initial_pose is not None and not args.no_mapping \
            and max(abs(pose[0]), abs(pose[1])) > COORD_LIMIT:
        # (an audit: taken, then every scan was refused as bad_points, exit 2)
        raise CliError(f'--initial-pose {args.initial_pose}: mapping holds coordinates within '
                       f'{COORD_LIMIT:g} m of the map origin; localize without mapping '
                       '(--no-mapping) up to 1e8 m')
    try:
        saved = read_map(args.map)
    except ValueError as exc:
        if not getattr(args, 'map_from_config', False):
            raise
        raise CliError(f'{args.config}: map_input_path: {exc} (a relative path is from the '
                       'current folder, as for the node)') from None
    if args.no_mapping and not len(saved.value):
        raise CliError(f'{args.map}: the saved map holds no segment: nothing to localize on '
                       '(--no-mapping would keep it empty)')
    return saved, pose


START_SCANS, START_SHARE = 10, 0.5
"""--map: the first scans used put at least this share of their points within 0.10 m of the
saved map, or replay warns (the robot is placed in the saved map at them)."""


def _off_the_saved_map(res, saved: MapValue) -> str:
    """Return a warning when the first scans do not lie on the saved map, else ''."""
    if not len(saved):
        return 'the saved map holds no segment: the scans were matched to each other only'
    sizes = res.session.scan_sizes()[:START_SCANS]
    share = map_metrics(res.points[:int(sizes.sum())], saved.segments)['coverage_0_10m']
    if share >= START_SHARE:
        return ''
    return (f'the first {len(sizes)} scans put {share * 100:.0f}% of their points on the saved '
            'map (within 0.10 m): is the initial pose right (--initial-pose X,Y,YAW_DEG), and '
            'the map of this place? The trajectory and the map are not registered to it')


SEEN_THROUGH_WARN = 0.10
"""``replay`` warns when the beams pass through more than this share of the map's length (the
judged ``contradicted_share``): maps of consistent scans stay under 3 % on the shared indoor logs
(7 % on fr079 without the free-space evidence; 19-21 % on the misregistered outdoor campus log,
which is warned of); a laser mount given 180 deg or 5 deg off, or drifting odometry unmatched,
gave 43-79 % in a new-user audit, and a TurtleBot-like bag of scans alone whose heading ended
27 deg off 17 % (25 %, the threshold before, let it through)."""


UNCOVERED_WARN = 0.85
"""``replay`` also warns when the map covers (within 0.10 m) less than this share of the points it
was made from: the free-space evidence cuts what later beams see through, so scans that
disagree (drifting odometry unmatched, a mount 5 deg off) leave a map the beams do not
contradict (8.5 and 5.0 % in a new-user audit) but that leaves a third and a quarter of the
points off it (coverage 66 and 74 %); consistent indoor replays cover 91-98 %."""


def _seen_through(stats: dict, args, range_noise: float = 0.0) -> str:
    """
    Return a warning when the scans disagree with each other, else ''.

    The beams pass through much of the map (``SEEN_THROUGH_WARN``) or the map leaves many of
    the points off (``UNCOVERED_WARN``). ``range_noise`` (the config's): named among the
    things to check when set (too high, it coarsens the map as bad poses do).
    """
    if not stats.get('segments'):
        return ''           # an empty map: its own warning says why (no segment), not the poses
    share = stats.get('contradicted_share')
    coverage = stats.get('coverage_0_10m')
    through = share is not None and share > SEEN_THROUGH_WARN
    off = coverage is not None and np.isfinite(coverage) and coverage < UNCOVERED_WARN
    if not (through or off):
        return ''
    if getattr(args, 'map', None) is not None:
        check = ['the initial pose (--initial-pose X,Y,YAW_DEG) and that the saved map is of '
                 'this place']
    elif getattr(args, 'scan_matching', False) or args.pose_source == 'scan':
        check = ['the poses']
    else:
        check = ['the poses (drifting odometry: --scan-matching)'
                 if hasattr(args, 'scan_matching') else 'the poses (drifting odometry: '
                 'replay --scan-matching)']
    if args.pose_source == 'odom':
        where = (f"{args.config}'s laser_x, laser_y, laser_yaw (rad), laser_upside_down, or "
                 if getattr(args, 'mount_from_config', False) else '')
        check.insert(0, f"the laser's mount ({where}--laser-mount: a laser facing backwards has "
                        'yaw 180, one upside down flip)')
    if range_noise:
        check.append(f"range_noise ({range_noise:g}: the lidar's range error as a share of the "
                     'range; too high, it coarsens the map)')
    what = [f"the beams pass through {share * 100:.0f}% of the map's length"] if through else []
    what += [f'the map leaves {(1 - coverage) * 100:.0f}% of the points more than 0.10 m off']\
        if off else []
    return f'{" and ".join(what)}: the scans disagree with each other; check {" and ".join(check)}'


LASER_PARAMS = ('laser_x', 'laser_y', 'laser_yaw', 'laser_upside_down')


def _node_set_specs() -> dict:
    """Return {name: spec} of the node's scalar parameters ``replay --set`` takes."""
    from .config import REPLAY_READS
    from .params import NODE_PARAMS
    return {spec.name: spec for spec in NODE_PARAMS if spec.name in REPLAY_READS
            and not isinstance(spec.default, (list, tuple))}


def _node_sets(items: list) -> tuple:
    """
    Split ``replay --set`` items: (node parameters of ``config.REPLAY_READS``, the rest).

    The node's scalar parameters replay takes (``--set scan_matching=false``,
    ``--set odom_frame=wheel_odom``) are typed by the parameter table; every other item is the
    mapper's (``load_incremental_config``), which refuses what it does not know.
    """
    from .config import typed_value
    specs = _node_set_specs()
    node, rest = {}, []
    for item in items:
        key, eq, value = item.partition('=')
        key = key.strip()
        if eq and key in specs:
            node[key] = typed_value(specs[key], value, '--set')
        else:
            rest.append(item)
    return node, rest


def _node_file(args, node_sets: dict) -> None:
    """
    Fill replay's pose and session options from a ROS 2 parameter file (``--config``).

    The node parameters that place and group the scans (``config.REPLAY_READS``) are taken as
    the node with that file takes them (``config.read_node_file``: its checks; a
    ``map_input_path`` with its ``initial_pose``, in radians, the node's default [0, 0, 0] when
    the file gives none), with ``node_sets`` (``--set``) over it; a flag on the command line
    wins. ``fixed_frame`` and the laser mount count only when the file sets them off their
    defaults (or ``--set`` does): at the defaults replay finds them (the TF tree's 'map' or
    root; the mount on /tf_static), as it does without a file, and ``_node_differs`` says
    when the node would not. Sets ``args.session_extra`` (SessionOptions fields without a
    flag), ``args.file_initial_pose``, ``args.from_config`` (the names taken) and
    ``args.node_file`` (the ``config.NodeFile``).
    """
    from .config import read_node_file
    nf = read_node_file(args.config, node_sets, args.map)
    s, names = nf.settings, nf.names
    taken, extra = [], {}

    def take(name, attr, value, unset=None):
        if getattr(args, attr) == unset and name in names:
            setattr(args, attr, value)
            taken.append(name)
    if s is not None:
        take('pose_source', 'pose_source', s.pose_source)
        take('fixed_frame', 'fixed_frame', s.fixed_frame)
        take('update_every_n_scans', 'update_every_n_scans', s.update_every_n_scans)
        if 'scan_matching' in names and s.scan_matching and not args.scan_matching:
            args.scan_matching = True
            taken.append('scan_matching')
        if s.input_path and args.map is None:
            args.map = s.input_path
            args.map_from_config = True
            taken.append('map_input_path')
        if args.map is not None and args.initial_pose is None and (
                'initial_pose' in names or getattr(args, 'map_from_config', False)):
            args.file_initial_pose = s.initial_pose     # the node's (its default: the origin)
            taken += ['initial_pose'] if 'initial_pose' in names else []
        if args.scan_matching or args.map is not None or args.pose_source == 'scan':
            take('chord_knots', 'chord_knots', s.chord_knots)   # (the node's, unused without)
        if not s.mapping and not args.no_mapping:
            args.no_mapping = True
            taken.append('mapping')
        for name, field in (('odom_frame', 'odom_frame'), ('transform_tolerance', 'tolerance'),
                            ('transform_timeout', 'wait'), ('transform_cache', 'cache_seconds'),
                            ('odom_gap_factor', 'odom_gap_factor'),
                            ('scan_time_offset', 'scan_time_offset'),
                            ('grid_resolution', 'grid_resolution')):
            if name in names:
                value = getattr(s, name)
                extra[field] = (value or None) if name == 'odom_frame' else value
                taken.append(name)
    if args.pose_source is None:
        args.pose_source = 'tf'
    if args.update_every_n_scans is None:
        args.update_every_n_scans = 1
    laser = [name for name in LASER_PARAMS if name in names]
    if laser and args.laser_mount is None and args.pose_source == 'odom':
        # The node's mount in odom mode, exactly (radians): the text is what stats record.
        extra.update(mount=(s.laser_x, s.laser_y, s.laser_yaw),
                     mount_upside_down=s.laser_upside_down)
        args.laser_mount = (f'{s.laser_x:g},{s.laser_y:g},{math.degrees(s.laser_yaw):g}'
                            + (',flip' if s.laser_upside_down else ''))
        args.mount_from_config = True
        taken += laser
    args.session_extra, args.from_config, args.node_file = extra, taken, nf


def _node_file_warnings(nf, where: str, tool: str) -> list:
    """
    Return the one-line warnings on a parameter file's node parameters (``config.NodeFile``).

    Names the node does not have, the live node's own parameters ``tool`` does not use, and
    other nodes' blocks; ``where``: the file (or '--set').
    """
    from .params import NODE_NAME
    out = []
    if nf.unknown:
        out.append(f'{where}: parameters the node does not have, not used: '
                   f'{", ".join(nf.unknown)}')
    if nf.live_only:
        out.append(f'{where}: live node parameters, not used by {tool}: '
                   f'{", ".join(nf.live_only)}')
    if nf.skipped:
        out.append(f'{where}: blocks of other nodes not read: {", ".join(nf.skipped)} ({tool} '
                   f'reads {NODE_NAME} and /**; for a node under another name, key its block '
                   'so)')
    return out


def _node_differs(args, session) -> list:
    """
    Return warnings where the node, given ``--config``, would place the scans otherwise.

    ``fixed_frame`` and the odom-mode laser mount at their defaults are found by replay (the TF
    tree's 'map' or root; the scan frame's mount on /tf_static); the node takes the
    parameters as they are: 'map', and (0, 0, 0) in odom mode.
    """
    nf = getattr(args, 'node_file', None)
    if nf is None or nf.settings is None or not nf.states or args.config is None:
        return []               # (a file of smemsf / incremental entries only says nothing)
    s = nf.settings
    out = []
    found = session.fixed_frame
    odom = session.poses.odom_frame
    if args.scan_matching and odom is not None and odom == found:
        out.append(f'{args.config}: with scan matching the map frame must be above the '
                   f"odometry frame, and fixed_frame is the odometry's own ({odom!r}): the "
                   f'node would broadcast no {odom} -> {odom} (tf_frames): set fixed_frame: map')
    if found and args.fixed_frame is None and found != s.fixed_frame:
        out.append(f'{args.config}: the node with this file maps in fixed_frame {s.fixed_frame!r}'
                   f' (the default), replay found {found!r}: add fixed_frame: {found} to the '
                   'file for the node to map as replay did')
    if args.pose_source == 'odom' == s.pose_source and args.laser_mount is None:
        mounts = set()
        for frame in session.scan_frames:
            under = session.poses.static_mount(frame)
            m = None if under is None else under[1]
            if m is not None and (max(abs(m.x), abs(m.y), abs(m.yaw)) > 1e-6 or m.flip):
                # as doubles (0.0, not 0: the node refuses integers)
                mounts.add(f'laser_x: {float(m.x)!r}, laser_y: {float(m.y)!r}, '
                           f'laser_yaw: {float(m.yaw)!r}'
                           + (', laser_upside_down: true' if m.flip else ''))
        if mounts:
            out.append(f'{args.config}: the node with this file (pose_source odom) places the '
                       f'laser at laser_x/y/yaw 0, 0, 0; replay took the mount on /tf_static '
                       f'({"; ".join(sorted(mounts))}): set those in the file for the node')
    return out


def cmd_replay(args) -> int:
    from .replay import run_replay
    node_sets, core_sets = _node_sets(args.set)
    config = load_incremental_config(args.config, core_sets, _node_set_specs())
    try:
        _node_file(args, node_sets)
    except ValueError as exc:           # ConfigError: one line naming the file
        raise CliError(str(exc)) from None
    for line in _node_file_warnings(args.node_file, args.config or '--set', 'replay'):
        print(f'polyline-mapper: warning: {line}', file=sys.stderr)
    check_outputs([args.output, args.plot], [args.input, args.config, args.map])
    _suffixes(args.output, args.plot)
    start, pose = _start_map(args)
    if start is not None:               # checked here to name the file and the option
        from .session import require_noise_scale
        try:
            require_noise_scale(start.value, config.smemsf.sigma is not None,
                                'give one with --set sigma=M')
        except ValueError as exc:
            raise CliError(f'{args.map}: {exc}') from None
    if args.loop_closure and (not args.scan_matching or start is not None
                              or args.pose_source != 'odom'):
        raise CliError('--loop-closure needs --scan-matching and --pose-source odom, '
                       'and a new map (not --map)')
    options = _replay_options(args, args.every, args.update_every_n_scans,
                              args.scan_matching or start is not None)
    t0 = time.perf_counter()
    res = run_replay(args.input, config, options, args.scan_topic, args.odom_topic,
                     progress=not args.quiet, mapping=not args.no_mapping, start_map=start,
                     initial_pose=pose, loop_closure=args.loop_closure)
    for line in res.warnings:
        print(f'polyline-mapper: warning: {line}', file=sys.stderr)
    if res.used == 0:
        raise CliError(f'{args.input}: {res.nothing_mapped()}')
    saved_off = [_off_the_saved_map(res, start.value)] if start is not None else []
    for line in res.skip_lines() + saved_off + _node_differs(args, res.session):
        if line:
            print(f'polyline-mapper: warning: {line}', file=sys.stderr)
    value = res.map_value
    disagree = _seen_through(value.stats, args, config.smemsf.range_noise)
    if disagree:
        print(f'polyline-mapper: warning: {disagree}', file=sys.stderr)
    value.stats.update(total_seconds=round(time.perf_counter() - t0, 3),
                       laser_mount=args.laser_mount)
    if args.from_config:        # the node parameters --config and --set gave (_node_file)
        value.stats['node_parameters'] = args.from_config
    if start is not None:
        value.stats.update(start_map=os.path.basename(args.map), mapping=not args.no_mapping)
    save_map(value, res.points, args.output, args.plot,
             title=f'{os.path.basename(os.path.normpath(args.input))} (replay): '
                   f'{len(value.segments)} segments', config=config_dict(config),
             inputs=[args.input, args.config, args.map],
             grid=res.session.occupancy(value.segments))
    if not args.quiet:
        print(res.summary(args.output))
    return 0


POSE_ARGS = (('pose_source', 'tf'), ('scan_topic', None), ('odom_topic', None),
             ('fixed_frame', None), ('laser_mount', None), ('scan_time_offset', None))
"""The options (argparse dest, default) that place a bag's or a drive's scans."""


def read_beams_any(path: str, args, range_max: float = None) -> tuple:
    """
    Points of a point file, a CARMEN log, a bag or a drive, with their laser positions.

    Returns ``(points, origins, description, posed)``; ``origins`` is None for a point file.
    Bags and simulated drives are registered as replay does, without mapping (``range_max``:
    logs only); ``posed`` is then what placed their scans, as replay's stats record it
    (``pose_source``, ``scan_topic``, ``odom_topic``, ``laser_mount``), else {}.
    """
    from .recordings import kind_of
    kind = kind_of(path)
    if kind in ('points', 'carmen'):
        # The recording options place a bag's or a drive's scans; a log's records carry their
        # corrected laser poses, a point file none: given here, they would change nothing.
        given = [f'--{name.replace("_", "-")}' for name, default in POSE_ARGS + (
            ('chord_knots', None),) if getattr(args, name, default) != default]
        if given:
            what = ('a point file' if kind == 'points' else
                    'a CARMEN log (its corrected laser poses place its scans; replay it for '
                    'other pose sources)')
            raise CliError(f'{" and ".join(given)} {"does" if len(given) == 1 else "do"} not '
                           f'apply to {what}')
        return read_input(path, range_max, not args.quiet) + ({},)
    if range_max is not None:
        raise CliError('--range-max applies to CARMEN logs only')
    res = _register(path, args)
    st = res.map_value.stats
    posed = {key: st.get(key) for key in ('pose_source', 'scan_topic', 'odom_topic',
                                          'fixed_frame')}
    extra = {'scan_time_offset': args.scan_time_offset} if args.scan_time_offset else {}
    return (res.points, res.session.origins(), st.get('input_type', 'scans'),
            {**posed, 'laser_mount': args.laser_mount, **extra})


def _register(path: str, args):
    """Replay ``path`` without mapping (the scans registered as replay does); the result."""
    from .replay import run_replay
    options = _replay_options(args)
    res = run_replay(path, None, options, args.scan_topic, args.odom_topic,
                     progress=not args.quiet, mapping=False)
    for line in res.warnings:
        print(f'polyline-mapper: warning: {line}', file=sys.stderr)
    if res.used == 0:
        raise CliError(f'{path}: {res.nothing_mapped()}')
    for line in res.skip_lines():       # as replay says them: scans left out of the points
        print(f'polyline-mapper: warning: {line}', file=sys.stderr)
    return res


STAMP_MATCH = 1e-5
"""Seconds: a scan and a map's trajectory row closer in stamp are the same scan (rows: 1 us)."""


def _beams_for_map(args, value: MapValue) -> tuple:
    """
    Beams of ``--points`` where the map placed them: ``(points, origins, note)``.

    A map with a trajectory (``replay``; with ``--scan-matching`` the poses are the mapper's
    own, not the input's) has one row per scan it used: the input's scans are registered as
    replay does, without mapping, and each is moved rigidly from its pose to the row of the
    same stamp, so the beams are those the map's stats judged; scans without a row are left
    out. Without a trajectory, or when no stamp matches (another recording: warned), the
    input as ``read_beams_any`` gives it. ``note``: the summary's words on it, or ''.

    The scans are registered with the pose options given; with none given and ``--points``
    the map's own input (its file name), with those its replay or fit recorded
    (``_recorded_pose_args``), so a map made with ``--pose-source odom --laser-mount ...`` is
    drawn over its beams without repeating them.
    """
    from .core.geometry import se2_compose, se2_inverse
    from .recordings import kind_of
    traj = value.trajectory
    if kind_of(args.points) == 'points':
        return read_beams_any(args.points, args)[:2] + ('',)
    args, posed = _recorded_pose_args(args, value.stats or {})
    if traj is None or not len(traj):
        return read_beams_any(args.points, args)[:2] + (f' ({posed[2:]})' if posed else '',)
    res = _register(args.points, args)
    points, origins = res.points, res.session.origins()
    own, sizes = res.map_value.trajectory, res.session.scan_sizes()
    order = np.argsort(traj[:, 0], kind='stable')
    stamps = traj[order, 0]
    hi = np.clip(np.searchsorted(stamps, own[:, 0]), 0, len(stamps) - 1)
    lo = np.maximum(hi - 1, 0)
    row = np.where(np.abs(stamps[lo] - own[:, 0]) < np.abs(stamps[hi] - own[:, 0]), lo, hi)
    found = np.abs(stamps[row] - own[:, 0]) <= STAMP_MATCH
    if len(own) != len(sizes) or not found.any():
        print(f"polyline-mapper: warning: {args.points}: none of its scans is in the map's "
              'trajectory (stamps differ: another recording?); drawn at its own poses',
              file=sys.stderr)
        return points, origins, ''
    fix = se2_compose(traj[order[row[found]], 1:], se2_inverse(own[found, 1:]))
    keep = np.repeat(found, sizes)
    fix = np.repeat(fix, sizes[found], axis=0)

    def move(q):                        # each point by its scan's fix (se2_compose broadcasts)
        q = q[keep]
        return se2_compose(fix, np.column_stack([q, np.zeros(len(q))]))[:, :2]
    return move(points), move(origins), (f" at the map's trajectory ({int(found.sum())} of "
                                         f'{len(found)} scans{posed})')


def _recorded_pose_args(args, stats: dict) -> tuple:
    """
    Return ``args`` with the pose options the map recorded, when none is given, and a note.

    The options are those the map's replay or fit recorded.

    Taken only when ``--points`` names the map's own input (``stats['input']``, its file name)
    and the stats record a pose source; ``fixed_frame`` is not taken (a replay's scans are
    moved onto its trajectory whatever frame they are registered in; a fit records none).
    ``note``: the options taken, for the summary, or ''. Options given with another pose
    source than the map's: one warning (a replay's trajectory holds the robot base's poses,
    which in scan mode is the laser: scans registered otherwise land off by the mount).
    """
    recorded = stats.get('pose_source')
    if recorded not in ('tf', 'odom', 'scan') or \
            stats.get('input') != os.path.basename(os.path.normpath(args.points)):
        return args, ''
    if getattr(args, 'pose_given', False) or \
            any(getattr(args, name, default) != default for name, default in POSE_ARGS):
        if args.pose_source != recorded:
            print(f'polyline-mapper: warning: {args.points}: the map was made with '
                  f'--pose-source {recorded}; registered with --pose-source '
                  f'{args.pose_source}, its scans may be drawn off where the map placed them '
                  "(leave the pose options out to use the map's own)", file=sys.stderr)
        offset = stats.get('scan_time_offset') or 0.0
        if offset != (args.scan_time_offset or 0.0):
            # (the scans are matched to the trajectory by stamp: another offset pairs each
            # with another scan's pose, silently)
            print(f'polyline-mapper: warning: {args.points}: the map was made with '
                  f'--scan-time-offset {offset:g}; registered with {args.scan_time_offset or 0:g}'
                  ", its scans are drawn at other scans' poses (give the same value, or leave "
                  "the pose options out to use the map's own)", file=sys.stderr)
        return args, ''
    taken = {'pose_source': stats['pose_source']}
    if stats['pose_source'] == 'odom':
        taken.update(odom_topic=stats.get('odom_topic'), laser_mount=stats.get('laser_mount'))
    if stats.get('scan_topic'):
        taken['scan_topic'] = stats['scan_topic']
    if stats.get('scan_time_offset'):
        taken['scan_time_offset'] = stats['scan_time_offset']
    if (stats.get('chord_knots') and stats['pose_source'] == 'scan'
            and getattr(args, 'chord_knots', None) is None):
        # scan mode registers the scans by matching them (a review: an arc map's bag was
        # registered with median knots, 401 of its 405 scans)
        taken['chord_knots'] = stats['chord_knots']
    flags = ' '.join(f'--{name.replace("_", "-")} {value}' for name, value in taken.items()
                     if value is not None and (name, value) not in POSE_ARGS)
    return argparse.Namespace(**{**vars(args), **taken}), (
        f', posed as when mapped: {flags}' if flags else '')


def cmd_plot(args) -> int:
    from .formats.mapjson import read_map
    # Given or not (None): ``_recorded_pose_args`` takes the map's own options only when no
    # pose option is given, so an explicit --pose-source tf is the user's too.
    args.pose_given = args.pose_source is not None
    args.pose_source = args.pose_source or 'tf'
    inputs = [args.map, args.points]
    check_outputs([args.output], inputs)
    _suffixes(png=args.output)
    if args.free_space and not args.points:
        raise CliError('--free-space needs --points INPUT: a CARMEN log or a bag with the beams')
    data = read_map(args.map)
    value = data.value
    if args.free_space:
        return _plot_free_space(args, value, inputs)
    points, _, note = _beams_for_map(args, value) if args.points else (None, None, '')
    title = args.title or (f'{os.path.basename(args.map)}: {len(value)} segments, '
                           f'{len(value.polylines)} polylines')
    save_map(value, points, None, args.output, title=title, inputs=inputs)
    if not args.quiet:
        print(f'wrote {args.output}: {len(value)} segments'
              + (f' over {len(points)} points{note}' if points is not None else ''))
    return 0


def _plot_free_space(args, value: MapValue, inputs: list) -> int:
    """``plot --free-space``: beams of ``--points`` under the map, contradicted segments red."""
    from .core.freespace import judge
    from .plot import plot_free_space
    points, origins, note = _beams_for_map(args, value)
    if origins is None:
        raise CliError(f'{args.points}: a point file has no beams; --free-space needs a CARMEN '
                       'log or a bag')
    verdict = judge(value.segments, points, origins)
    title = args.title or (f'{os.path.basename(args.map)}: {len(value)} segments, '
                           f'{verdict.share * 100:.1f}% of map length contradicted')
    png = io.BytesIO()
    plot_free_space(png, points, origins, value.segments, verdict.contradicted, title=title)
    with OutputSet(inputs) as out:
        out.add(args.output)
        out.put(args.output, png.getvalue())
    if not args.quiet:
        print(f'wrote {args.output}: {len(value)} segments, {verdict.beams} beams{note}, '
              f'{int(verdict.contradicted.sum())} segments contradicted '
              f'({verdict.share * 100:.1f}% of map length)')
    return 0


def cmd_export(args) -> int:
    from .formats.export import export_map, export_trajectory, map_yaml_image
    from .formats.mapjson import read_map
    check_outputs([args.output], [args.map])
    ext = os.path.splitext(args.output)[1].lower().lstrip('.')
    ext = 'yaml' if ext == 'yml' else ext
    if args.format and ext in ('geojson', 'svg', 'csv', 'yaml', 'tum') and ext != args.format:
        print(f'polyline-mapper: warning: writing {args.format} into {args.output}, whose '
              f'extension says {ext} (--format {args.format} decides)', file=sys.stderr)
    data = read_map(args.map)
    if args.trajectory or (args.format or '') == 'tum' or ext == 'tum':
        fmt = export_trajectory(data, args.output, args.format, inputs=[args.map])
        stamps = data.value.trajectory[:, 0]
        back = int((stamps[1:] <= np.maximum.accumulate(stamps)[:-1]).sum())
        if back:
            # (a recording whose clock restarted: a bag played twice, a simulation reset;
            # TUM tools such as evo expect increasing stamps; an audit)
            print(f'polyline-mapper: warning: {args.output}: {back} of the '
                  f'{len(data.value.trajectory)} poses are stamped at or before an earlier '
                  "one (the recording's clock went back): tools that read TUM or CSV "
                  'trajectories expect increasing stamps', file=sys.stderr)
        if not args.quiet:
            print(f'wrote {args.output}: the trajectory, {len(data.value.trajectory)} poses '
                  f'({"TUM" if fmt == "tum" else "CSV t,x,y,yaw"})')
        return 0
    if args.resolution is not None and args.trajectory:
        raise CliError('--resolution applies to the map_server YAML + PGM export, not to a '
                       'trajectory')
    fmt = export_map(data, args.output, args.format, inputs=[args.map],
                     resolution=args.resolution)
    if not args.quiet and fmt == 'yaml':
        omitted = (data.value.stats or {}).get('grid_omitted')
        link = (f' (a link to {os.path.realpath(args.output)})'
                if os.path.islink(args.output) else '')
        what = ('the stored planner map' if data.grid is not None else
                'the map has no segment: one unknown cell, no free space without a wall'
                if not len(data.value) else
                'no planner map stored' + (f' (it was too large for the map file: {omitted})'
                                           if omitted else '')
                + ': segments occupied, the rest unknown')
        print(f'wrote {args.output}{link} and {map_yaml_image(args.output)[0]}: the map_server '
              f'pair ({what})')
    elif not args.quiet:
        print(f'wrote {args.output}: {fmt}, {len(data.value.polylines)} polylines, '
              f'{len(data.value)} segments')
    return 0


CONVERT_REFUSED = {
    'bag': 'a bag: replay, fit, plot and play read bags (rosbag2 and ROS 1) as they are',
    'sim': 'a simulated drive: replay, fit, plot and play read it as it is',
    'points': 'a point file (for fit and plot --points)',
}
"""What ``convert`` says of the inputs it does not take, by ``recordings.kind_of``."""


def cmd_convert(args) -> int:
    from .formats.carmen_bag import carmen_to_bag
    from .formats.output import check_new_folder
    from .recordings import kind_of
    try:
        kind = kind_of(args.input)
    except ValueError:
        kind = None                     # any other name is read as a CARMEN log, as before
    if kind in CONVERT_REFUSED:
        raise CliError(f'{args.input}: convert writes a rosbag2 from a CARMEN log, and this is '
                       f'{CONVERT_REFUSED[kind]}')
    check_new_folder(args.output, [args.input])
    bar = _progress_factory(not args.quiet, 'convert', 'msg')
    info = carmen_to_bag(args.input, args.output, args.storage, args.period, progress=bar,
                         drift_seed=args.odom_drift)
    if info['skipped']:
        print(f"polyline-mapper: warning: {args.input}: skipped {info['skipped']} malformed "
              f"laser record(s), e.g. {info['skipped_examples'][0]}", file=sys.stderr)
    if info['stamps_made_up']:
        print(f'polyline-mapper: warning: {args.input}: log times do not increase; made-up '
              f'stamps {args.period:g} s apart, from t = 1 s', file=sys.stderr)
    if not args.quiet:
        off = info['laser_offset']
        tree = ('odom -> base_link drifting like wheel odometry (seed '
                f'{args.odom_drift}), no map frame' if args.odom_drift is not None
                else 'map -> odom -> base_link')
        print(f"wrote {args.output}: rosbag2 ({args.storage}), {info['scans']} scans on /scan "
              f'(frame laser), /tf {tree}, /tf_static base_link -> laser '
              f'({off[0]:g}, {off[1]:g}, {np.rad2deg(off[2]):g} deg), /odom')
    return 0


def number(lo: float = None, hi: float = None, lo_open: bool = False, kind=float):
    """
    Make an argparse type for finite values of ``kind`` within [lo, hi] (lo excluded if open).

    Refuses nan, inf and out-of-range values with one line naming the bound.
    """
    what = 'an integer' if kind is int else 'a number'

    def shown(bound) -> str:        # an integer's bounds in full (not 4.29497e+09)
        return str(int(bound)) if kind is int and float(bound).is_integer() else f'{bound:g}'
    if lo == 0 and lo_open and hi is None:
        rule = f'a positive {"integer" if kind is int else "number"}'
    elif lo is not None and hi is not None:
        rule = f'{what} in [{shown(lo)}, {shown(hi)}]'
    elif lo is not None:
        rule = f'{what} {">" if lo_open else ">="} {shown(lo)}'
    else:
        rule = f'{what} <= {shown(hi)}' if hi is not None else f'a finite {what[2:]}'

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'must be {rule}, got {text!r}') from None
        low = lo is not None and (value <= lo if lo_open else value < lo)
        if not math.isfinite(value) or low or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f'must be {rule}, got {text!r}')
        return value
    parse.__name__ = kind.__name__
    return parse


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line: ``polyline-mapper: error: ...``."""

    def error(self, message: str):
        """Print one line and exit 2 (``--rate must be ...`` for a refused option value)."""
        message = re.sub(r'^argument (?:[^:/]+/)?([^:]+): must be', r'\1 must be', message)
        if message.endswith('required: command'):          # (no command given at all)
            commands = [name for action in self._actions
                        if isinstance(action, argparse._SubParsersAction)
                        for name in action.choices]
            message += f' (one of: {", ".join(commands)}; COMMAND --help says more)'
        self.exit(EXIT_USAGE, f'polyline-mapper: error: {message}\n')


SECONDS = number(0.0)
POSITIVE = number(0.0, lo_open=True)


def _pose_args(sp, plot: bool = False, replay: bool = False) -> None:
    """Add the options that place a bag's or a drive's scans (``replay``: its own wording)."""
    sp.add_argument('--scan-topic', help='sensor_msgs/LaserScan topic (default: the only one)')
    # None when not given: plot then takes the map's own, else 'tf'; replay its --config's
    # pose_source, else 'tf' (_node_file)
    sp.add_argument('--pose-source', choices=('tf', 'odom', 'scan'),
                    default=None if plot or replay else 'tf',
                    help='tf: laser pose in the fixed frame from /tf and /tf_static ('
                    + ("default: the map's own with its input, else tf" if plot else 'default')
                    + '); odom: nav_msgs/Odometry plus the laser mount, map in the odometry '
                    'frame; scan: no pose data, each scan predicted at constant velocity and '
                    'refined by scan matching (' + ('implies --scan-matching' if replay else
                                                    'as replay --pose-source scan')
                    + "; the first scan at the origin of the map frame, 'map' unless "
                    '--fixed-frame)')
    sp.add_argument('--fixed-frame', type=_frame,
                    help="map frame with --pose-source tf (default: 'map' "
                    "when the scan's TF tree has it, else the tree's root; with scan matching "
                    "'map' above that root) or with --pose-source odom and scan matching "
                    "(default: 'map'; without matching the map is in the odometry frame)")
    sp.add_argument('--odom-topic', help='nav_msgs/Odometry topic for --pose-source odom '
                    '(default: the only one)')
    sp.add_argument('--laser-mount', metavar='X,Y,YAW_DEG[,flip]',
                    help='--pose-source odom: the laser pose on the odometry child frame (m, m, '
                    "deg; flip: mounted upside down), like the node's laser_* parameters; "
                    "default: the scan frame's mount from /tf_static")
    sp.add_argument('--scan-time-offset', type=number(-10.0, 10.0), metavar='SECONDS',
                    help="added to every scan's stamp before it is posed (the node's "
                    'scan_time_offset): -0.1 for a laser driver that stamps its scans 0.1 s '
                    'late; with scan matching a replay estimates the lag and warns '
                    '(scan_clock) with the value to give')
    from .core.register import CHORD_KNOTS
    sp.add_argument('--chord-knots', choices=CHORD_KNOTS,
                    help=('scan matching' if replay else 'with --pose-source scan')
                    + ": the last scans' chord knots every 0.15 m of an arc of median steps "
                    '(median, the default) or of the raw arc (arc, the default before '
                    "2026-11-30, which turns every match a little the same way); the node's "
                    'chord_knots')


def build_parser() -> argparse.ArgumentParser:
    from .recordings import sim_names
    drives = f'a built-in drive: {sim_names()}'
    p = _Parser(prog='polyline-mapper',
                description='2D polyline maps from laser scans (SMEMSF).')
    sub = p.add_subparsers(dest='command', required=True)

    def common(sp):
        sp.add_argument('-o', '--output', required=True, help='map JSON to write')
        sp.add_argument('--plot', metavar='PNG', help='also write a PNG of points and map')
        sp.add_argument('--config', metavar='FILE', help='YAML/JSON with SMEMSFConfig keys, '
                        'or a ROS 2 parameter file (config/polyline_mapper.yaml; replay also '
                        'takes the node parameters that place the scans from it, flags win)')
        sp.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                        help='override one config key (repeatable), e.g. --set sigma=0.02')
        sp.add_argument('-q', '--quiet', action='store_true', help='no progress, no summary')

    f = sub.add_parser('fit', help='fit a map to an (N, 2) point file, a CARMEN log or a bag')
    f.add_argument('input', help='.npy/.csv/.txt points (metres), CARMEN .log/.log.gz, a '
                   f'bag (registered as replay does, then fitted at once), or {drives}; '
                   'a log, bag or drive is fitted with its beams (what they see through is cut '
                   'out; --set free_space_window=0 fits the bare points)')
    common(f)
    f.add_argument('--frame-id', default=None, type=_frame,
                   help="frame of the map (default: a bag's or drive's fixed frame, as "
                        "replay's; else map)")
    f.add_argument('--range-max', type=POSITIVE, default=None,
                   help='for logs: ignore readings beyond this range (m)')
    _pose_args(f)
    f.set_defaults(func=cmd_fit)

    d = sub.add_parser('demo', help='map a simulated office drive with the live node (or '
                       'offline with --offline)')
    common(d)
    d.add_argument('--noise', type=number(0.0, 10.0), default=0.01,
                   help='laser range noise (m, default 0.01)')
    d.add_argument('--seed', type=number(0, 2 ** 32 - 1, kind=int), default=1,
                   help='simulation seed (default 1)')
    d.add_argument('--rate', type=POSITIVE, default=1.0,
                   help='live: play the drive at this many times real time (default 1)')
    d.add_argument('--domain-id', type=number(0, 232, kind=int), metavar='N',
                   help='live: ROS_DOMAIN_ID to run on (default: a random one in 1-101, '
                   'discovery on this machine only, so the demo never reaches a robot)')
    d.add_argument('--offline', action='store_true',
                   help="no ROS: fit all the drive's points at once (batch) in this process; "
                   '--config / --set are then fit parameters, not node parameters')
    d.set_defaults(func=cmd_demo)

    r = sub.add_parser('replay', help='map a bag or CARMEN log scan by scan (incremental)')
    r.add_argument('input', help='rosbag2 folder, .db3, .mcap, ROS 1 .bag, CARMEN .log(.gz), '
                   f'or {drives} (sim:office_dynamic: people walking, a door opening, a box '
                   'carried away; the free-space evidence clears them, --set '
                   'free_space_window=0 leaves them)')
    common(r)
    _pose_args(r, replay=True)
    r.add_argument('--every', type=number(1, kind=int), default=1, metavar='N',
                   help='use every N-th scan')
    r.add_argument('--scan-matching', action='store_true',
                   help='refine each scan pose against the map built so far (for odometry '
                   'that drifts or poorly known poses); the map is in the fixed frame')
    r.add_argument('--loop-closure', action='store_true',
                   help='with --scan-matching and --pose-source odom: after the replay, close '
                   'the loops of its trajectory (offline) and map the recording again on the '
                   'closed trajectory')
    r.add_argument('--update-every-n-scans', type=number(1, 1000, kind=int), default=None,
                   metavar='N', help="one map update per N posed scans, as the node's "
                   'update_every_n_scans parameter (the same map as the node given N)')
    r.add_argument('--map', metavar='SAVED.json', help='start from a saved map (a MAP.json of '
                   'fit or replay) and localize on it: turns --scan-matching on (the poses of '
                   'INPUT are registered to the map by matching); the output is in its frame')
    r.add_argument('--initial-pose', metavar='X,Y,YAW_DEG', help='with --map: the robot (the '
                   'frame the laser is mounted on) in the map at the first scan (m, m, deg); '
                   "default: where INPUT's poses put it")
    r.add_argument('--no-mapping', action='store_true', help='with --map: keep the map fixed '
                   '(localization only): OUT holds the saved map unchanged, bit for bit, and '
                   'the trajectory')
    r.set_defaults(func=cmd_replay)

    pl = sub.add_parser('plot', help='draw a map JSON as a PNG, over points if given')
    pl.add_argument('map', help='map JSON (from fit or replay)')
    pl.add_argument('-o', '--output', required=True, help='PNG to write')
    pl.add_argument('--points', metavar='INPUT', help='point file, CARMEN log or bag whose '
                    'points to draw underneath (bags are registered as replay does; a map with '
                    'a trajectory, e.g. from replay --scan-matching, places each scan at its '
                    'row of the same stamp, as its stats did; with no pose option given, those '
                    "of the map's replay are used when INPUT is its input)")
    pl.add_argument('--free-space', action='store_true', help='draw the beams of --points '
                    '(a CARMEN log or bag) and the segments they contradict in red')
    pl.add_argument('--title', help='figure title')
    pl.add_argument('-q', '--quiet', action='store_true', help='no progress, no summary')
    _pose_args(pl, plot=True)
    pl.set_defaults(func=cmd_plot)

    e = sub.add_parser('export', help='write a map JSON as GeoJSON, SVG, CSV, or the map_server '
                       'YAML + PGM pair for planners')
    e.add_argument('map', help='map JSON (from fit or replay)')
    e.add_argument('-o', '--output', required=True, help='OUT.geojson, OUT.svg, OUT.csv or '
                   'OUT.yaml (writes OUT.pgm beside it); with --trajectory OUT.csv or OUT.tum')
    e.add_argument('--format', choices=('geojson', 'svg', 'csv', 'yaml', 'tum'),
                   help='format (default: from the output suffix)')
    e.add_argument('--trajectory', action='store_true', help="write the map's trajectory "
                   '(one pose per scan, from replay) instead of its segments: CSV t,x,y,yaw or '
                   'TUM (timestamp tx ty tz qx qy qz qw)')
    e.add_argument('--resolution', type=POSITIVE, default=None, metavar='M',
                   help='YAML + PGM of a map without a stored planner grid (fit): cell size in '
                   'metres (default 0.05)')
    e.add_argument('-q', '--quiet', action='store_true', help='no summary')
    e.set_defaults(func=cmd_export)

    py = sub.add_parser('play', help='publish a bag, CARMEN log or simulated drive on live '
                        'topics with its timing (scan, odom, /tf, /tf_static, /clock)')
    py.add_argument('input', help='rosbag2 folder, .db3, .mcap, ROS 1 .bag, CARMEN .log(.gz), '
                    f'or {drives}')
    py.add_argument('--rate', type=POSITIVE, default=1.0,
                    help='time scale (default 1: as recorded)')
    py.add_argument('--loop', action='store_true', help='play again and again (stamps shifted '
                    'by the recording length each pass, so time never runs backwards)')
    py.add_argument('--no-clock', action='store_true', help='do not publish /clock')
    py.add_argument('--clock-hz', type=POSITIVE, default=40.0, help='/clock ticks per second '
                    'between messages (default 40)')
    py.add_argument('--scan-topic', help='bags: LaserScan topic (default: the only one)')
    py.add_argument('--odom-topic', help='bags: Odometry topic (default: the only one, if any)')
    py.add_argument('--wait-for-subscriber', type=SECONDS, default=0.0, metavar='SECONDS',
                    help='wait up to this long for a subscriber on the scan topic first')
    py.add_argument('--seed', type=number(0, 2 ** 32 - 1, kind=int), default=1,
                    help='sim: drives: simulation seed (default 1)')
    py.add_argument('--noise', type=number(0.0, 10.0), default=0.01,
                    help='sim: drives: range noise (m, default 0.01)')
    py.add_argument('--period', type=POSITIVE, default=1.0, help='CARMEN logs: seconds between '
                    'scans when the log times do not increase (default 1)')
    py.add_argument('-q', '--quiet', action='store_true', help='no progress, no summary')
    py.add_argument('--ros-args', nargs=argparse.REMAINDER, default=None,
                    help='ROS arguments, e.g. --ros-args -r /scan:=/front/scan')
    py.set_defaults(func=cmd_play)

    rm = sub.add_parser('record-map', help='save the map a running node publishes (JSON, PNG)')
    rm.add_argument('topic', nargs='?', default='polyline_map',
                    help='polyline_mapper_msgs/PolylineMap topic (default: polyline_map)')
    rm.add_argument('-o', '--output', required=True, help='map JSON to write')
    rm.add_argument('--plot', metavar='PNG', help='also write a PNG of the map')
    rm.add_argument('--grid-topic', default=None, metavar='TOPIC',
                    help="the node's planner map (nav_msgs/OccupancyGrid), stored with the map "
                    "for export (default: map beside the map's topic, /robot1/map for "
                    "/robot1/polyline_map; '' for none)")
    rm.add_argument('--once', action='store_true', help='save the first map received and stop')
    rm.add_argument('--idle', type=SECONDS, metavar='SECONDS',
                    help='stop once no new map came for this long (default: run until Ctrl-C '
                    'or SIGTERM; either writes the newest map and exits 0)')
    rm.add_argument('--timeout', type=SECONDS, default=30.0, metavar='SECONDS',
                    help='give up (exit 2) if no map arrives within this long (default 30); 0: '
                    'wait forever')
    rm.add_argument('-q', '--quiet', action='store_true', help='no summary')
    rm.add_argument('--ros-args', nargs=argparse.REMAINDER, default=None,
                    help='ROS arguments, e.g. --ros-args -r __ns:=/robot1')
    rm.set_defaults(func=cmd_record_map)

    c = sub.add_parser('convert', help='convert a CARMEN log to a rosbag2 (scan, tf, odom)')
    c.add_argument('input', help='CARMEN .log / .log.gz')
    c.add_argument('-o', '--output', required=True, help='rosbag2 folder to create')
    c.add_argument('--storage', choices=('sqlite3', 'mcap'), default='sqlite3',
                   help='rosbag2 storage (default: sqlite3)')
    c.add_argument('--period', type=POSITIVE, default=1.0,
                   help='seconds between scans when the log times do not increase (default 1)')
    c.add_argument('--odom-drift', type=number(0, 2 ** 32 - 1, kind=int), metavar='SEED',
                   help='write a robot without a localizer: /odom and /tf odom -> base_link '
                   'drift like wheel odometry (5 %% of each step per axis, 0.02 rad + 1 deg '
                   'per metre of heading; seeded), no map frame')
    c.add_argument('-q', '--quiet', action='store_true', help='no progress, no summary')
    c.set_defaults(func=cmd_convert)
    return p


def _names_printable() -> None:
    """
    Print any file name, whatever the locale.

    A name with a byte that is not UTF-8 is kept by Python as a lone surrogate; under a UTF-8
    locale stdout refused it (UnicodeEncodeError) after the files were written, so a
    successful command ended with an error and exit 2. It is escaped instead (a backslash and
    its code), as stderr already does.
    """
    reconfigure = getattr(sys.stdout, 'reconfigure', None)
    if reconfigure is not None:
        try:
            reconfigure(errors='backslashreplace')
        except (ValueError, OSError):            # a stream that cannot change: left as it is
            pass


_NEGATIVE_LIST = re.compile(r'-[0-9.][0-9.eE+-]*(,[^,]*){2,3}$')
_NEGATIVE_NUMBER = re.compile(r'-([0-9.]\S*|inf|infinity|nan)$', re.IGNORECASE)
_NEGATIVE_VALUED = {'--initial-pose': _NEGATIVE_LIST, '--laser-mount': _NEGATIVE_LIST,
                    '--scan-time-offset': _NEGATIVE_NUMBER}
"""Options whose value may start with '-', and the form such a value takes."""


def _join_negative_values(argv: list) -> list:
    """
    Join a negative value to its option: ``--laser-mount -0.1,0,180`` -> ``--laser-mount=...``.

    argparse takes a value starting with '-' for an option and stops with 'expected one
    argument', unless it is a plain negative number: a pose list, or a number in exponent form
    (``--scan-time-offset -1e-1``); ``-inf``, ``-nan`` and ``-1x`` are joined too, so the
    option's own check names them. The options as argparse takes them, abbreviated too.
    """
    out, it = [], iter(argv)
    for item in it:
        out.append(item)
        form = next((f for name, f in _NEGATIVE_VALUED.items()
                     if item.startswith('--') and len(item) > 2 and name.startswith(item)), None)
        nxt = next(it, None) if form is not None else None
        if nxt is not None:
            out[-1:] = [f'{item}={nxt}'] if form.match(nxt) else [item, nxt]
    return out


def main(argv=None) -> int:
    """Entry point; returns the process exit code."""
    _names_printable()
    parser = build_parser()
    try:
        args = parser.parse_args(_join_negative_values(sys.argv[1:] if argv is None else argv))
    except SystemExit as exc:            # usage errors (exit 2) and --help (0), already printed
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    try:
        return args.func(args)
    except (CliError, ValueError) as exc:
        print(f'polyline-mapper: error: {exc}', file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:
        print(f'polyline-mapper: error: {exc.filename or ""}: {exc.strerror or exc}',
              file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print('polyline-mapper: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
