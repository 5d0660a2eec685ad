"""The planner map over DDS: nav_msgs/OccupancyGrid on 'map' from the real node."""

import subprocess
import sys

import numpy as np
from polyline_mapper.recordings import drive_messages
from polyline_mapper.ros.qos import MAP_QOS
import pytest
from rosnode import map_segments, NodeProcess, Peer, stamp_of
from std_srvs.srv import Trigger

pytest.importorskip('tf2_msgs.msg', reason='tf2_msgs is not built (run tools/dev.sh setup)')
pytestmark = [pytest.mark.slow, pytest.mark.dds]
RATE = 40.0
TIMEOUT = 60.0
RES = 0.1


def _grids(peer: Peer) -> list:
    from nav_msgs.msg import OccupancyGrid
    got = []
    peer.node.create_subscription(OccupancyGrid, 'map', got.append, MAP_QOS)
    return got


def _cells(msg) -> np.ndarray:
    from polyline_mapper.ros.messages import grid_from_msg
    return grid_from_msg(msg).data


def _centres(msg, mask) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    origin = np.array([msg.info.origin.position.x, msg.info.origin.position.y])
    return origin + (np.stack([cols, rows], axis=1) + 0.5) * msg.info.resolution


@pytest.fixture(scope='module')
def grid_run(office_drive, tmp_path_factory):
    """Run the node on the office drive; a late subscriber takes the grid after the drive."""
    folder = tmp_path_factory.mktemp('node_grid')
    node = NodeProcess(folder, {'map_output_path': str(folder / 'map.json'),
                                'map_publish_period': 0.1, 'grid_resolution': RES,
                                'grid_publish_period': 0.3, 'transform_timeout': 0.3,
                                # off its default, where the drive's 541 beams never reach it:
                                # record-map must store the node's value
                                'incremental.max_scan_points': 6000,
                                # every scan mapped however loaded the machine (the default
                                # 1 s latency dropped 5 of 223 in a dds run alone, and
                                # record-map rightly warned of it)
                                'max_scan_latency': 0.0, 'scan_buffer_size': 400})
    peer = Peer('test_peer_grid')
    late = None
    try:
        assert peer.wait_for_node(TIMEOUT), 'the node did not come up:\n' + node.stderr()
        live = _grids(peer)
        last = peer.play(list(drive_messages(office_drive)), RATE)
        assert peer.spin_until(lambda: peer.maps and stamp_of(peer.maps[-1]) == pytest.approx(
            last, abs=1e-6), TIMEOUT), node.stderr()[-3000:]
        assert peer.spin_until(lambda: live and stamp_of(live[-1]) == pytest.approx(
            last, abs=1e-6), TIMEOUT), node.stderr()[-3000:]
        late = Peer('test_peer_grid_late')
        grids = _grids(late)
        assert late.spin_until(lambda: grids, 20.0), 'a late subscriber got no grid'
        yield node, peer, late, grids, live, last, folder
    finally:
        if late is not None:
            late.close()
        peer.close()
        node.stop()


def test_a_late_subscriber_gets_the_grid_of_the_map(grid_run):
    _, peer, _, grids, live, last, _ = grid_run
    assert len(grids) == 1                       # depth 1, transient local: the newest only
    msg = grids[0]
    assert msg.header.frame_id == 'map' and stamp_of(msg) == pytest.approx(last, abs=1e-6)
    assert msg.info.resolution == pytest.approx(RES)
    assert msg.info.width * msg.info.height == len(msg.data)
    assert np.array_equal(_cells(msg), _cells(live[-1]))
    assert 2 <= len(live) <= 2 + (len(peer.maps)), 'the grid is published at a bounded rate'
    assert set(np.unique(_cells(msg))) == {-1, 0, 100}


def test_no_grid_without_a_wall_reaches_the_planners(grid_run):
    # A planner-map audit: the grids of the first updates (while the noise scale was
    # estimated) held the traced free space and no occupied cell, a map a planner allowing
    # unknown cells drives through; late subscribers got it until the next grid.
    _, _, _, _, live, _, _ = grid_run
    assert live and all((_cells(g) == 100).any() for g in live), \
        [int((_cells(g) == 100).sum()) for g in live]


def test_occupied_cells_are_the_polylines_and_free_cells_the_traced_beams(grid_run,
                                                                          office_drive):
    _, peer, _, grids, _, _, _ = grid_run
    msg = grids[0]
    cells = _cells(msg)
    segs = map_segments(peer.maps[-1])
    # occupied: within one cell of a map segment, and every segment drawn
    occ = _centres(msg, cells == 100)
    a, d = segs[:, 0], segs[:, 1] - segs[:, 0]
    t = np.clip(np.einsum('nkj,kj->nk', occ[:, None] - a, d) / np.einsum('kj,kj->k', d, d), 0, 1)
    dist = np.linalg.norm(occ[:, None] - (a + t[..., None] * d), axis=2).min(axis=1)
    assert dist.max() <= RES * np.sqrt(0.5) + 1e-6
    assert len(occ) >= np.linalg.norm(d, axis=1).sum() / RES * 0.9
    # free: every free cell is crossed by a traced beam (laser pose -> reading, map frame)
    spec = office_drive.spec
    angles = spec.angle_min + spec.angle_increment * np.arange(office_drive.ranges.shape[1])
    samples = []
    step = 0.25 * RES
    for pose, ranges in zip(office_drive.poses, office_drive.ranges):
        ok = np.isfinite(ranges) & (ranges > spec.range_min) & (ranges < spec.range_max)
        n = np.ceil(ranges[ok] / step).astype(int) + 1
        beam = np.repeat(np.arange(len(n)), n)
        k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        r = np.minimum(k * step, ranges[ok][beam])
        ang = pose[2] + angles[ok][beam]
        samples.append(pose[:2] + r[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1))
    origin = np.array([msg.info.origin.position.x, msg.info.origin.position.y])
    w, h = msg.info.width, msg.info.height
    touched = np.zeros((h, w), dtype=bool)          # cells the beams pass (sampled densely)
    for part in samples:
        c = np.floor((part - origin) / RES).astype(int)
        c = c[(c[:, 0] >= 0) & (c[:, 0] < w) & (c[:, 1] >= 0) & (c[:, 1] < h)]
        touched[c[:, 1], c[:, 0]] = True
    free = cells == 0
    assert free.sum() > 1000
    assert touched[free].mean() > 0.99              # (a corner clip may escape the samples)
    near = touched.copy()                           # ... but never by more than a cell
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        near |= np.roll(np.roll(touched, dr, axis=0), dc, axis=1)
    assert near[free].all()
    # and the rooms the laser saw are free: most touched cells are (the rest: walls, ends)
    assert free[touched].mean() > 0.8
    assert (cells[touched] == -1).mean() < 0.1


def test_record_map_stores_the_grid_the_node_publishes(grid_run, tmp_path):
    # record-map took only the polylines: its file exported for map_server had no free cell
    # (the node's ~/save_map stored the grid). Now it keeps the newest grid with the map.
    from polyline_mapper.formats.mapjson import config_dict, read_map
    from polyline_mapper.params import mapper_config
    from test_planner_export import load_like_map_server
    _, _, _, grids, _, last, _ = grid_run
    out = tmp_path / 'recorded.json'
    rec = subprocess.run([sys.executable, '-m', 'polyline_mapper.cli', 'record-map', '-o',
                          str(out), '--once', '--timeout', '20'], capture_output=True,
                         text=True, timeout=120)
    assert rec.returncode == 0 and 'with its planner map' in rec.stdout, rec.stderr
    assert 'warning' not in rec.stderr, rec.stderr
    saved = read_map(out)
    # the mapper settings the node mapped with, read from the node (the file had none)
    want = config_dict(mapper_config({'incremental.max_scan_points': 6000}))
    assert saved.config == want and saved.config['max_scan_points'] == 6000
    assert saved['stats']['stamp'] == pytest.approx(last, abs=1e-6)
    assert saved['stats']['grid_stamp'] == pytest.approx(last, abs=1e-6)
    # and the noise scale the node's /diagnostics report, as its ~/save_map writes it: without
    # it the file could not be localized on ('the map has no noise scale', new-user audit)
    assert grid_run[1].call('/polyline_mapper_node/save_map', Trigger).success
    by_node = read_map(grid_run[6] / 'map.json')['stats']
    assert 0 < saved['stats']['sigma'] < 0.05 and 0 < saved['stats']['r']
    assert (saved['stats']['sigma'], saved['stats']['r']) == pytest.approx(
        (by_node['sigma'], by_node['r']), rel=1e-6)
    assert np.array_equal(saved.grid.data, _cells(grids[0]))
    # the node's scan counts, so a map short of scans the node dropped says so (a docs audit:
    # a live play at 25x lost 387 of 910 scans, and only the node's exit summary told)
    st = saved['stats']
    assert st['scans_dropped'] == 0 and st['scans_used'] == st['scans_received'] > 0, st
    assert saved.grid.origin == pytest.approx((grids[0].info.origin.position.x,
                                               grids[0].info.origin.position.y))
    # ... and export hands map_server the free space the node's grid holds, cell for cell
    cli = subprocess.run([sys.executable, '-m', 'polyline_mapper.cli', 'export', str(out), '-o',
                          str(tmp_path / 'recorded.yaml')], capture_output=True, text=True,
                         timeout=120)
    assert cli.returncode == 0, cli.stderr
    loaded, meta = load_like_map_server(tmp_path / 'recorded.yaml')
    assert np.array_equal(loaded, _cells(grids[0])) and (loaded == 0).sum() > 1000
    assert meta['origin'][:2] == pytest.approx(saved.grid.origin)


def test_save_map_stores_the_grid_and_the_resolution_is_read_only(grid_run):
    from polyline_mapper.formats.mapjson import read_map
    _, peer, _, grids, _, _, folder = grid_run
    resp = peer.call('/polyline_mapper_node/save_map', Trigger)
    assert resp is not None and resp.success, resp
    grid = read_map(folder / 'map.json').grid
    assert grid is not None and grid.resolution == pytest.approx(RES)
    assert np.array_equal(grid.data, _cells(grids[0]))
    assert grid.origin == pytest.approx((grids[0].info.origin.position.x,
                                         grids[0].info.origin.position.y))
    res = peer.set_parameters(grid_resolution=0.2)
    assert res is not None and not res[0].successful
    # ~/reset forgets the free space too: the next grid has no free cell
    n = len(grids)
    assert peer.call('/polyline_mapper_node/reset', Trigger).success
    late = grid_run[2]
    assert late.spin_until(lambda: len(grids) > n, 20.0)
    assert not (_cells(grids[-1]) == 0).any()
    res = peer.set_parameters(grid_publish_period=0.0)
    assert res is not None and res[0].successful
