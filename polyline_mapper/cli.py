"""
``polyline-mapper``: the command line, a thin shell over the core.

Subcommands:
  fit INPUT -o MAP.json [--plot MAP.png] [--config FILE]   fit a map to a point file or CARMEN log
  demo -o MAP.json [--plot MAP.png]                         fit a simulated office floor

Errors in input, files or configuration end the program with exit code 2 and one line saying
why; no output file is left behind by a failed run.
"""

import argparse
import os
import sys
import tempfile
import time

import numpy as np

from .core import fit, map_metrics, SMEMSFConfig
from .formats.mapjson import map_to_dict, set_default_mode, write_json_atomic

EXIT_USAGE = 2


class CliError(Exception):
    """An error to report as one line with exit code 2."""


def load_config(path: str = None, overrides: list = ()) -> SMEMSFConfig:
    """
    Build the fit configuration from an optional YAML/JSON file and ``key=value`` overrides.

    The file is either a flat mapping of SMEMSFConfig keys, or a ROS 2 parameter file
    (``node_name: ros__parameters: {...}``) whose ``smemsf.*`` or plain keys are used.
    """
    values = {}
    if path:
        import yaml
        try:
            with open(path, 'r', encoding='utf-8') as fh:
                data = yaml.safe_load(fh) or {}
        except FileNotFoundError:
            raise CliError(f'{path}: no such config file') from None
        except (OSError, yaml.YAMLError) as exc:
            raise CliError(f'{path}: unreadable config ({exc.__class__.__name__})') from None
        if not isinstance(data, dict):
            raise CliError(f'{path}: a config file must hold a mapping')
        values = _flatten_ros_params(data)
    for item in overrides:
        key, sep, raw = item.partition('=')
        if not sep:
            raise CliError(f'--set expects key=value, got {item!r}')
        values[key.strip()] = _yaml_value(raw)
    try:
        return SMEMSFConfig.from_dict(values)
    except (TypeError, ValueError) as exc:
        raise CliError(f'bad config: {exc}') from None


def _yaml_value(text: str):
    import yaml
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        raise CliError(f'cannot parse value {text!r}') from None


def _flatten_ros_params(data: dict) -> dict:
    """Accept a flat mapping or a ROS 2 parameter file; return SMEMSFConfig keys."""
    for node in data.values():
        if isinstance(node, dict) and 'ros__parameters' in node:
            params = node['ros__parameters'] or {}
            sub = params.get('smemsf', params)
            known = set(SMEMSFConfig.__dataclass_fields__)
            return {k: v for k, v in sub.items() if k in known}
    return dict(data)


def read_input(path: str, range_max: float = None, progress: bool = True) -> tuple:
    """Read an (N, 2) point file or a CARMEN log; return points and a description."""
    low = path.lower()
    if low.endswith(('.log', '.log.gz', '.clf', '.clf.gz')):
        from .formats.carmen import read_carmen
        log = read_carmen(path)
        bar = _progress_factory(progress, 'register', 'scan')
        pts = log.points(range_max=range_max, progress=bar)
        desc = f'CARMEN log, {len(log.records)} scans'
        if log.skipped:
            desc += f', {log.skipped} malformed record(s) skipped'
            print(f'polyline-mapper: warning: {path}: skipped {log.skipped} malformed laser '
                  f'record(s), e.g. {log.skipped_examples[0]}', file=sys.stderr)
        return pts, desc
    if low.endswith(('.npy', '.csv', '.txt', '.xy')):
        from .formats.points import read_points
        pts = read_points(path)
        if range_max is not None:
            raise CliError('--range-max applies to laser logs only')
        return pts, 'point file'
    raise CliError(f'{path}: unknown input type (expected .npy, .csv, .txt, .log or .log.gz)')


def _progress_factory(enabled: bool, desc: str, unit: str):
    if not enabled:
        return None
    from tqdm import tqdm

    def wrap(items):
        return tqdm(items, desc=desc, unit=unit, leave=False, disable=None, file=sys.stderr)
    return wrap


def run_fit(points: np.ndarray, config: SMEMSFConfig, progress: bool = True):
    """Fit with a progress bar over iterations (shown on a terminal only)."""
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
        return fit(points, config, progress=tick)
    finally:
        if bar is not None:
            bar.close()


def write_outputs(result, points, config, out_json: str, out_png: str = None,
                  frame_id: str = 'map', title: str = '', truth=None, extra=None) -> dict:
    """Write the map JSON (and PNG) atomically; return the stats written."""
    stats = map_metrics(points, result.segments)
    stats.update(iterations=int(result.iterations), converged=bool(result.converged),
                 seconds=round(float(result.seconds), 3), polylines=len(result.polylines),
                 sigma=float(result.sigma), r=float(result.r))
    stats.update(extra or {})
    data = map_to_dict(result.segments, result.polylines, result.closed, result.support, stats,
                       config.to_dict(), frame_id)
    tmp_png = None
    try:
        if out_png:
            from .plot import plot_map
            folder = os.path.dirname(os.path.abspath(out_png))
            os.makedirs(folder, exist_ok=True)
            fd, tmp_png = tempfile.mkstemp(prefix='.tmp-', suffix='.png', dir=folder)
            os.close(fd)
            plot_map(tmp_png, points, result.segments, result.polylines, title=title,
                     truth=truth)
        write_json_atomic(out_json, data)
        if tmp_png:
            set_default_mode(tmp_png)
            os.replace(tmp_png, out_png)
            tmp_png = None
    finally:
        if tmp_png and os.path.exists(tmp_png):
            os.unlink(tmp_png)
    return stats


def summary_line(path: str, stats: dict) -> str:
    """One line a person reads after a run."""
    return (f"wrote {path}: {stats['segments']} segments in {stats['polylines']} polylines from "
            f"{stats['points']} points, mean distance {stats['mean_distance'] * 100:.2f} cm, "
            f"p95 {stats['p95_distance'] * 100:.2f} cm, coverage "
            f"{stats['coverage_0_10m'] * 100:.1f}%, {stats['iterations']} iterations, "
            f"{stats['seconds']:.1f} s")


def cmd_fit(args) -> int:
    config = load_config(args.config, args.set)
    t0 = time.perf_counter()
    points, desc = read_input(args.input, args.range_max, not args.quiet)
    if len(points) < 2:
        raise CliError(f'{args.input}: {len(points)} usable point(s); need at least 2')
    result = run_fit(points, config, not args.quiet)
    stats = write_outputs(result, points, config, args.output, args.plot, args.frame_id,
                          title=f'{os.path.basename(args.input)}: {len(result.segments)} segments',
                          extra={'input': os.path.basename(args.input), 'input_type': desc,
                                 'total_seconds': round(time.perf_counter() - t0, 3)})
    if not args.quiet:
        print(summary_line(args.output, stats))
    return 0


def cmd_demo(args) -> int:
    from .sim import LaserSpec, office_floor, simulate_drive
    config = load_config(args.config, args.set)
    world = office_floor()
    drive = simulate_drive(world, LaserSpec(noise=args.noise), rng=args.seed)
    points = drive.points()
    result = run_fit(points, config, not args.quiet)
    stats = write_outputs(result, points, config, args.output, args.plot, 'map',
                          title=f'simulated office floor: {len(result.segments)} segments',
                          truth=world.walls, extra={'input': 'simulated office floor',
                                                    'scans': int(len(drive.poses))})
    if not args.quiet:
        print(summary_line(args.output, stats))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='polyline-mapper',
                                description='2D polyline maps from laser scans (SMEMSF).')
    sub = p.add_subparsers(dest='command', required=True)

    def common(sp):
        sp.add_argument('-o', '--output', required=True, help='map JSON to write')
        sp.add_argument('--plot', metavar='PNG', help='also write a PNG of points and map')
        sp.add_argument('--config', metavar='FILE', help='YAML/JSON with SMEMSFConfig keys, '
                        'or a ROS 2 parameter file (config/polyline_mapper.yaml)')
        sp.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                        help='override one config key (repeatable), e.g. --set sigma=0.02')
        sp.add_argument('-q', '--quiet', action='store_true', help='no progress, no summary')

    f = sub.add_parser('fit', help='fit a map to an (N, 2) point file or a CARMEN log')
    f.add_argument('input', help='.npy/.csv/.txt points (metres) or CARMEN .log/.log.gz')
    common(f)
    f.add_argument('--frame-id', default='map', help='frame of the points (default: map)')
    f.add_argument('--range-max', type=float, default=None,
                   help='for logs: ignore readings beyond this range (m)')
    f.set_defaults(func=cmd_fit)

    d = sub.add_parser('demo', help='simulate a drive through an office floor and fit it')
    common(d)
    d.add_argument('--noise', type=float, default=0.01, help='laser range noise (m)')
    d.add_argument('--seed', type=int, default=1, help='simulation seed')
    d.set_defaults(func=cmd_demo)
    return p


def main(argv=None) -> int:
    """Entry point; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
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
