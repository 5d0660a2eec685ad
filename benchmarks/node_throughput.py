"""
Throughput of the live node: a 40 Hz stream of 720-beam scans for 60 s over DDS.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/node_throughput.py [--seconds 60] [--rate 40] [--beams 720]

Starts ``polyline_mapper_node`` (the installed console script, default parameters except
``map_publish_period:=0``, so every update is published) in its own process, and from this
process publishes a simulated drive through the office floor (270 deg, 12 m, 1 cm noise) as
LaserScan + /tf (map -> odom -> base_link) + a /tf_static laser mount, paced at the rate.

Reported:

- scans sent / received by the node / used in updates / dropped from its queue / skipped, and
  the node's update count: "no dropped updates" means every sent scan was used;
- CPU of the node process (user + system time from /proc/<pid>/stat over the streaming
  window, as a share of one core) and its peak RSS;
- update time (the mapper's update, from the node's summary line) and end-to-end latency: wall
  time from publishing a scan to receiving the PolylineMap stamped with it, percentiles;
- map quality against the simulated walls (segments farther than 0.15 m from any wall).

Writes benchmarks/results/node-throughput.json and the ``node-throughput`` block of
benchmarks/README.md.
"""

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time

from common import HERE, stamp, write_readme
import numpy as np
from polyline_mapper.core.geometry import sample_segments
from polyline_mapper.sim import LaserSpec, office_floor, simulate_drive
from polyline_mapper.sim.world import path_poses


def proc_times(pid: int) -> tuple:
    """Return (user + system CPU seconds, RSS bytes) of a process from /proc."""
    with open(f'/proc/{pid}/stat') as fh:
        fields = fh.read().rsplit(')', 1)[1].split()
    ticks = os.sysconf('SC_CLK_TCK')
    cpu = (int(fields[11]) + int(fields[12])) / ticks
    rss = int(fields[21]) * os.sysconf('SC_PAGE_SIZE')
    return cpu, rss


def make_drive(scans: int, beams: int):
    """Drive the office path with the step that gives ``scans`` scans."""
    world = office_floor()
    length = np.sum(np.linalg.norm(np.diff(np.asarray(world.path, float), axis=0), axis=1))
    step = length / scans
    spec = LaserSpec(beams=beams, noise=0.01)
    drive = simulate_drive(world, spec, step=step, rng=11)
    n = len(path_poses(world.path, step))
    return drive, n


def run(seconds: float, rate: float, beams: int, matching: bool = False) -> dict:
    """Stream the drive into a fresh node; return the measurements."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from polyline_mapper.ros.qos import MAP_QOS
    from polyline_mapper.recordings import drive_messages
    from polyline_mapper.ros.messages import scan_msg, transform_msg
    from polyline_mapper.ros.qos import TF_QOS, TF_STATIC_QOS
    from polyline_mapper_msgs.msg import PolylineMap
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage

    count = int(round(seconds * rate))
    t_sim = time.perf_counter()
    drive, _ = make_drive(count, beams)
    drive_seconds = time.perf_counter() - t_sim
    # With matching the map frame starts on the odometry frame (no map -> odom is sent), so
    # odom is put on map for the wall check.
    msgs = list(drive_messages(drive, mount=(0.2, 0.0, 0.0),
                               map_to_odom=(0.0, 0.0, 0.0) if matching else (0.5, -0.3, 0.1)))
    static = next(r for _, topic, r in msgs if topic == '/tf_static')
    transforms = [r for _, topic, r in msgs if topic == '/tf']
    if matching:            # a robot without a localizer: odom -> base_link only, no map frame
        transforms = [[tr for tr in group if tr.parent != 'map'] for group in transforms]
    scans = [r for _, topic, r in msgs if topic == '/scan']
    count = min(count, len(scans))

    exe = os.path.join(os.path.dirname(sys.executable), 'polyline_mapper_node')
    err = tempfile.NamedTemporaryFile('w+', suffix='.stderr', delete=False)
    params = ['-p', 'map_publish_period:=0.0', '-p', 'stats_period:=10.0']
    params += ['-p', 'scan_matching:=true'] if matching else []
    node = subprocess.Popen([exe, '--ros-args'] + params, stderr=err, stdout=subprocess.DEVNULL,
                            env=dict(os.environ, RCUTILS_COLORIZED_OUTPUT='0'))
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    peer = rclpy.create_node('throughput_peer', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(peer)
    scan_pub = peer.create_publisher(LaserScan, 'scan', qos_profile_sensor_data)
    tf_pub = peer.create_publisher(TFMessage, '/tf', TF_QOS)
    static_pub = peer.create_publisher(TFMessage, '/tf_static', TF_STATIC_QOS)
    received = {}

    def on_map(m):
        received[(m.header.stamp.sec, m.header.stamp.nanosec)] = (time.monotonic(),
                                                                  len(m.segments), m)
    peer.create_subscription(PolylineMap, 'polyline_map', on_map, MAP_QOS)

    def spin_until(cond, timeout):
        end = time.monotonic() + timeout
        while not cond() and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.01)
        return cond()
    try:
        if not spin_until(lambda: scan_pub.get_subscription_count() > 0
                          and tf_pub.get_subscription_count() > 0, 60.0):
            raise RuntimeError('the node did not come up: ' + open(err.name).read())
        spin_until(lambda: False, 1.0)          # let the node's readers match ours too
        static_pub.publish(TFMessage(transforms=[transform_msg(tr) for tr in static]))
        sent = {}
        t0_stamp = time.time()
        cpu0, _ = proc_times(node.pid)
        wall0 = time.monotonic()
        tick = wall0
        late = 0
        peak_rss = 0
        for i in range(count):
            st = t0_stamp + i / rate
            scan = scan_msg(scans[i], st)
            tf_pub.publish(TFMessage(transforms=[transform_msg(tr, st) for tr in transforms[i]]))
            scan_pub.publish(scan)
            sent[(scan.header.stamp.sec, scan.header.stamp.nanosec)] = time.monotonic()
            tick += 1.0 / rate
            if time.monotonic() > tick + 0.5 / rate:
                late += 1
            while time.monotonic() < tick:
                ex.spin_once(timeout_sec=max(0.0, tick - time.monotonic()))
            if i % 40 == 0:
                peak_rss = max(peak_rss, proc_times(node.pid)[1])
        last = (scan.header.stamp.sec, scan.header.stamp.nanosec)
        spin_until(lambda: last in received, 30.0)
        wall1 = time.monotonic()
        cpu1, rss = proc_times(node.pid)
        peak_rss = max(peak_rss, rss)
    finally:
        ex.shutdown()
        peer.destroy_node()
        rclpy.try_shutdown(context=ctx)
        node.send_signal(signal.SIGINT)
        try:
            node.wait(20)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()
    log = open(err.name).read()
    os.unlink(err.name)
    summary = next((ln for ln in log.splitlines() if 'summary:' in ln), '')
    got = re.search(r'(\d+) scans received, (\d+) used in (\d+) updates, (\d+) dropped', summary)
    if not got:
        raise RuntimeError('no summary line from the node:\n' + log[-3000:])
    node_received, used, updates, dropped = (int(v) for v in got.groups())

    def pct(line, key):
        m = re.search(key + r' p50 ([\d.]+) p95 ([\d.]+) p99 ([\d.]+) max ([\d.]+)', line)
        return dict(zip(('p50', 'p95', 'p99', 'max'), map(float, m.groups()))) if m else {}
    lat = np.array([1e3 * (received[k][0] - sent[k]) for k in sent if k in received])
    final = received.get(last, (None, 0, None))[2]
    segs = np.array([[[s.start.x, s.start.y], [s.end.x, s.end.y]] for s in final.segments]
                    ) if final is not None else np.zeros((0, 2, 2))
    samples, owner = sample_segments(segs, 0.02)
    worst = np.zeros(len(segs))
    np.maximum.at(worst, owner, drive.world.distance(samples))
    return {
        'rate_hz': rate, 'beams': beams, 'seconds': round(wall1 - wall0, 2),
        'scans_sent': count, 'scans_received': node_received, 'scans_used': used,
        'updates': updates, 'queue_dropped': dropped,
        'skipped': count - used, 'publisher_late_ticks': late,
        'maps_received': len(received),
        'maps_matching_a_scan': int(lat.size),
        'node_cpu_core_share': round((cpu1 - cpu0) / (wall1 - wall0), 3),
        'node_peak_rss_mib': round(peak_rss / 2 ** 20, 1),
        'update_ms': pct(summary, 'update_ms'),
        'node_latency_ms': pct(summary, 'latency_ms'),
        'end_to_end_latency_ms': {k: round(float(np.percentile(lat, q)), 1) for k, q in (
            ('p50', 50), ('p95', 95), ('p99', 99), ('max', 100))} if lat.size else {},
        'final_segments': int(len(segs)),
        'segments_off_wall_0_15m': int(np.sum(worst > 0.15)),
        'drive_simulation_seconds': round(drive_seconds, 1),
        'summary_line': summary.split(': ', 1)[-1],
    }


def table(r: dict, meta: dict) -> str:
    """Format the README block."""
    u, n, e = r['update_ms'], r['node_latency_ms'], r['end_to_end_latency_ms']
    lost = r['scans_sent'] - r['scans_received']
    if r['scans_used'] == r['scans_sent'] and r['queue_dropped'] == 0:
        verdict = 'kept up: every scan sent was used, no update dropped'
    elif r['scans_used'] == r['scans_received'] and r['queue_dropped'] == 0:
        # The scan input is best effort (sensor-data QoS, as laser drivers publish): DDS may
        # drop a sample before the node sees it, which says nothing about the node's speed.
        verdict = (f'kept up: every scan the node received was used, none dropped; {lost} of '
                   f"{r['scans_sent']} never reached it (best-effort sensor-data QoS: lost in "
                   'transport, not by the node)')
    else:
        verdict = (f"did not keep up: {r['scans_sent'] - r['scans_used']} of "
                   f"{r['scans_sent']} scans not used ({r['queue_dropped']} dropped from the "
                   f'queue, {lost} never received)')
    return (
        f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}, with "
        f"`{meta['command']}` (node with default parameters and map_publish_period:=0"
        + ('; scan_matching:=true, /tf without map -> odom' if '--scan-matching' in
           meta['command'] else '') + '; the publisher runs on the same 2 cores).\n\n'
        f'Result: {verdict}.\n\n'
        '| quantity | value |\n|---|---:|\n'
        f"| stream | {r['scans_sent']} scans x {r['beams']} beams at {r['rate_hz']:g} Hz "
        f"({r['seconds']:.1f} s) |\n"
        f"| scans received / used / dropped (queue) | {r['scans_received']} / "
        f"{r['scans_used']} / {r['queue_dropped']} |\n"
        f"| incremental updates (first 4 estimate the noise) | {r['updates']} |\n"
        f"| maps received (one per worker round) | {r['maps_received']} |\n"
        f"| node CPU (share of one core) | {100 * r['node_cpu_core_share']:.0f}% |\n"
        f"| node peak RSS | {r['node_peak_rss_mib']:.0f} MiB |\n"
        f"| update time p50 / p95 / p99 / max (ms) | {u['p50']:.1f} / {u['p95']:.1f} / "
        f"{u['p99']:.1f} / {u['max']:.1f} |\n"
        f'| scan arrival -> map updated, in the node, p50 / p95 / p99 / max (ms) | '
        f"{n['p50']:.1f} / {n['p95']:.1f} / {n['p99']:.1f} / {n['max']:.1f} |\n"
        f'| scan published -> PolylineMap received, p50 / p95 / p99 / max (ms) | '
        f"{e['p50']:.1f} / {e['p95']:.1f} / {e['p99']:.1f} / {e['max']:.1f} |\n"
        f"| final map: segments / farther than 0.15 m from a wall | {r['final_segments']} / "
        f"{r['segments_off_wall_0_15m']} |\n")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--seconds', type=float, default=60.0)
    parser.add_argument('--rate', type=float, default=40.0)
    parser.add_argument('--beams', type=int, default=720)
    parser.add_argument('--no-readme', action='store_true', help='do not update README.md')
    parser.add_argument('--scan-matching', action='store_true', help='the node with '
                        'scan_matching:=true and no map -> odom on /tf (a robot with odometry '
                        'only); results in node-throughput-matching.json and its own block')
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 50))
    r = run(args.seconds, args.rate, args.beams, args.scan_matching)
    name = 'node-throughput' + ('-matching' if args.scan_matching else '')
    command = 'python benchmarks/node_throughput.py' + ''.join(
        f' {a}' for a in (argv if argv is not None else sys.argv[1:]))
    meta = stamp(command)
    out = HERE / 'results' / f'{name}.json'
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({'meta': meta, 'result': r}, indent=1) + '\n')
    print(json.dumps(r, indent=1))
    if not args.no_readme:
        write_readme(name, table(r, meta))
    return 0


if __name__ == '__main__':
    sys.exit(main())
