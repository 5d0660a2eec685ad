"""
The live demo: the node, a simulated drive played to it, its map recorded and scored.

``polyline_mapper_node`` runs in its own process, the drive is played to it over DDS, and the
map it publishes is scored against the simulated points.

This is what ``polyline-mapper demo`` (and ``bash tools/dev.sh demo``) runs: the same three
pieces a user would start by hand (the node with ``use_sim_time:=true``, ``polyline-mapper play
sim:office``, ``polyline-mapper record-map``), in one command; the node runs on the drive's
clock (/clock from the player). Unless a domain is given, everything runs on a random
ROS_DOMAIN_ID in 1-101 (whose DDS ports stay clear of Linux's ephemeral ports) with discovery
limited to this machine, so the demo never talks to (or disturbs) a robot on the network.
"""

from dataclasses import dataclass
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import Callable, Optional

import numpy as np

from ..core import map_metrics
from ..core.mapvalue import MapValue
from ..formats.records import Scan
from ..params import NODE_NAME


@dataclass
class DemoResult:
    """The recorded map (MapValue), the drive's points and true walls, and the node log."""

    value: MapValue
    points: np.ndarray
    walls: np.ndarray
    node_log: str
    grid: object = None
    """The node's planner map (``core.grid.GridMap``) as of the map, or None."""
    config: Optional[dict] = None
    """The node's mapper settings (``formats.mapjson.config_dict``), or None."""


class DemoError(RuntimeError):
    """The live demo could not finish (the node did not start, answer or keep up)."""


def _node_command(params: dict, params_file: Optional[str]) -> list:
    cmd = [sys.executable, '-m', 'polyline_mapper.ros.node', '--ros-args']
    if params_file:
        cmd += ['--params-file', params_file]
    for key, value in params.items():
        cmd += ['-p', f'{key}:={value}']
    return cmd


def run_live_demo(world: str = 'sim:office', rate: float = 1.0, seed: int = 1,
                  noise: float = 0.01, params: dict = None, params_file: str = None,
                  domain_id: int = None, progress: bool = False, timeout: float = 30.0,
                  log: Callable[[str], None] = print) -> DemoResult:
    """
    Run the node, play ``world`` to it at ``rate``, return its final map with scores.

    ``params`` (name -> value text) and ``params_file`` go to the node as ``-p`` and
    ``--params-file``. Raises DemoError (one line) when the node fails or falls silent, and
    ValueError for a bad world or option.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from diagnostic_msgs.msg import DiagnosticArray
    from .player import first_scan_of, Player
    from .recorder import MapRecorder, take_map
    from ..recordings import open_recording

    if domain_id is None:
        domain_id = random.SystemRandom().randrange(1, 102)
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    elif not 0 <= domain_id <= 232:
        raise ValueError(f'a ROS domain id is in 0-232, got {domain_id}')
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), RCUTILS_COLORIZED_OUTPUT='0')
    node_params = {'use_sim_time': 'true', 'stats_period': '0.0', 'diagnostics_period': '0.5'}
    node_params.update(params or {})
    with open_recording(world, seed=seed, noise=noise) as rec, \
            tempfile.TemporaryFile('w+') as node_err:
        drive = rec.drive
        proc = subprocess.Popen(_node_command(node_params, params_file), env=env,
                                stdout=subprocess.DEVNULL, stderr=node_err)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        executor = SingleThreadedExecutor(context=context)
        spinner = None
        try:
            node = rclpy.create_node('polyline_mapper_demo', context=context)
            executor.add_node(node)
            recorder = MapRecorder(node, 'polyline_map')
            diag = {}

            def on_diagnostics(msg):
                for status in msg.status:
                    # '/polyline_mapper_node: mapping' (the node's full name)
                    if status.name.lstrip('/').startswith(NODE_NAME):
                        diag.clear()
                        diag.update({kv.key: kv.value for kv in status.values})
                        diag['_at'] = time.monotonic()
            node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
            spinner = threading.Thread(target=executor.spin, daemon=True)
            spinner.start()
            player = Player(node, rate=rate, clock=True)
            first_scan = first_scan_of(rec)
            started = (player.wait_for_subscriber(*first_scan, timeout)
                       and _wait(lambda: recorder.count > 0, proc, timeout))
            if not started:
                raise DemoError(f'the node did not come up within {timeout:g} s'
                                + _tail(node_err))
            time.sleep(0.5)     # discovery is two-sided: let the node's readers match ours
            bar = None
            if progress:
                from tqdm import tqdm
                bar = tqdm(total=rec.scan_count, desc='play', unit='scan', leave=False,
                           disable=None, file=sys.stderr)
                player.on_message = lambda topic, r: bar.update(1) if isinstance(r, Scan) \
                    else None
            try:
                stats = player.play(rec.messages)
            finally:
                if bar is not None:
                    bar.close()
            last = stats.last_scan_stamp
            # Done when the map holds the last scan and a diagnostics report followed it.
            done = _wait(lambda: recorder.stamp() >= last - 1e-6 and diag.get('_at', 0)
                         > (recorder.received_at or np.inf), proc, timeout)
            if not done:
                raise DemoError(f'the map did not reach the last scan within {timeout:g} s of '
                                'the end of the drive' + _tail(node_err))
            info = dict(diag)
            # What record-map writes too: the planner map as new as the map, the node's
            # settings and noise scale (a map to localize on, to export for Nav2).
            value, grid, config = take_map(recorder, node, _Spun())[:3]
        finally:
            executor.shutdown(timeout_sec=1.0)
            if spinner is not None:
                spinner.join(timeout=2.0)
            rclpy.try_shutdown(context=context)
            _stop(proc)
        node_err.seek(0)
        node_log = node_err.read()

    points = drive.points()
    value.stats.update(map_metrics(points, value.segments))
    value.stats.update(
        input=f'{world} (seed {seed}, noise {noise:g} m), played at {rate:g}x',
        scans=int(len(drive.poses)), scans_played=stats.scans,
        scans_used=int(info.get('scans_used', 0)),
        scans_dropped=int(info.get('scans_dropped', 0)),
        update_ms_median=_float(info.get('update_ms_p50')),
        update_ms_p99=_float(info.get('update_ms_p99')),
        latency_ms_median=_float(info.get('latency_ms_p50')),
        play_seconds=round(stats.wall_seconds, 2), play_max_delay_ms=round(stats.max_late_ms, 1))
    return DemoResult(value, points, np.asarray(drive.world.walls), node_log, grid, config)


class _Spun:
    """An executor stand-in for the recorder's waits while the demo's spins in its thread."""

    def spin_once(self, timeout_sec: float) -> None:
        time.sleep(timeout_sec)


def _float(text) -> Optional[float]:
    return None if text is None else float(text)


def _wait(condition, proc, timeout: float) -> bool:
    """Poll ``condition`` until it holds, the node process ends, or ``timeout`` s pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        if proc.poll() is not None:
            return bool(condition())
        time.sleep(0.05)
    return False


def _stop(proc) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5.0)


def _tail(fh) -> str:
    """Return the node's last stderr line (for an error message), or ''."""
    fh.flush()
    fh.seek(0)
    lines = [ln for ln in fh.read().splitlines() if ln.strip()]
    return f'; node said: {lines[-1].strip()}' if lines else '; the node printed nothing'
