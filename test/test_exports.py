"""Exports of a map JSON (GeoJSON, SVG, CSV) and the plot command."""

import csv
import io
import json
import re
import xml.etree.ElementTree as ET

from conftest import noisy_line
import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.formats.mapjson import read_map
import pytest

SVG = '{http://www.w3.org/2000/svg}'


@pytest.fixture(scope='module')
def fitted(tmp_path_factory):
    """Fit a closed 4 x 3 m room plus a separate 2 m wall; return folder, map path, map."""
    rng = np.random.default_rng(4)
    corners = [(0, 0), (4, 0), (4, 3), (0, 3), (0, 0)]
    parts = [noisy_line(a, b, 700, 0.01, rng) for a, b in zip(corners[:-1], corners[1:])]
    parts.append(noisy_line((6, 0.5), (6, 2.5), 500, 0.01, rng))
    pts = np.concatenate(parts)
    folder = tmp_path_factory.mktemp('fitted')
    np.save(folder / 'pts.npy', pts)
    out = folder / 'map.json'
    assert main(['fit', str(folder / 'pts.npy'), '-o', str(out), '-q']) == 0
    data = read_map(str(out))
    assert len(data['polylines']) == 2 and sorted(data['closed']) == [False, True]
    return folder, out, data


def test_geojson_linestrings_match_the_polylines(fitted, tmp_path):
    _, src, data = fitted
    out = tmp_path / 'map.geojson'
    assert main(['export', str(src), '-o', str(out), '-q']) == 0
    gj = json.loads(out.read_text())
    assert gj['type'] == 'FeatureCollection' and gj['frame_id'] == 'map'
    assert len(gj['features']) == len(data['polylines'])
    for f, poly, closed in zip(gj['features'], data['polylines'], data['closed']):
        assert f['type'] == 'Feature' and f['geometry']['type'] == 'LineString'
        coords = np.array(f['geometry']['coordinates'])
        want = np.array(poly + poly[:1]) if closed else np.array(poly)
        np.testing.assert_allclose(coords, want, atol=1e-9)
        assert f['properties']['closed'] == closed
        length = np.linalg.norm(np.diff(want, axis=0), axis=1).sum()
        assert f['properties']['length_m'] == pytest.approx(length, abs=1e-3)
    room = next(f for f in gj['features'] if f['properties']['closed'])
    assert room['properties']['length_m'] == pytest.approx(14.0, abs=0.1)


def test_svg_parses_with_y_up_and_a_scale_bar(fitted, tmp_path):
    _, src, data = fitted
    out = tmp_path / 'map.svg'
    assert main(['export', str(src), '-o', str(out), '-q']) == 0
    root = ET.parse(out).getroot()
    assert root.tag == SVG + 'svg'
    shapes = root.findall(f'.//{SVG}polyline') + root.findall(f'.//{SVG}polygon')
    assert len(shapes) == len(data['polylines'])
    assert len(root.findall(f'.//{SVG}polygon')) == 1          # the closed room
    wall = root.find(f'.//{SVG}polyline')                        # the wall from y 0.5 to 2.5
    xy = np.array([[float(v) for v in p.split(',')] for p in wall.get('points').split()])
    poly = np.array(next(p for p, c in zip(data['polylines'], data['closed']) if not c))
    # higher map y -> smaller SVG y (y up); 50 px per metre by default
    order = np.argsort(poly[:, 1])
    assert np.all(np.diff(xy[order, 1]) < 0)
    assert abs(np.ptp(xy[:, 1]) - 50 * np.ptp(poly[:, 1])) < 0.5
    bar = root.find(f".//{SVG}g[@id='scale-bar']")
    line, text = bar.find(SVG + 'line'), bar.find(SVG + 'text')
    metres = float(re.match(r'([\d.]+) m', text.text).group(1))
    assert metres in (1, 2, 5) and float(line.get('x2')) - float(line.get('x1')) == \
        pytest.approx(50 * metres, abs=0.2)
    # A frame_id with characters XML cannot hold (an export audit: U+FFFE made the file not
    # well-formed) is written with U+FFFD in their place, the markup escaped.
    from polyline_mapper.formats.export import to_svg
    odd = dict(data, frame_id='map\ufffe\x01<&>\U0001f916')
    title = ET.fromstring(to_svg(odd).encode('utf-8')).find(SVG + 'title').text
    assert title.startswith('map\ufffd\ufffd<&>\U0001f916: ')


def test_csv_has_one_row_per_segment(fitted, tmp_path, capsys):
    _, src, data = fitted
    out = tmp_path / 'segs.csv'
    assert main(['export', str(src), '-o', str(out), '-q']) == 0
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert len(rows) == len(data['segments'])
    got = np.array([[float(r[k]) for k in ('x1', 'y1', 'x2', 'y2')] for r in rows])
    np.testing.assert_allclose(got, np.array(data['segments']), atol=1e-4)
    np.testing.assert_allclose([float(r['support']) for r in rows], data['support'], atol=0.01)
    # --format wins over the suffix
    txt = tmp_path / 'segs.txt'
    assert main(['export', str(src), '-o', str(txt), '--format', 'csv', '-q']) == 0
    assert txt.read_text() == out.read_text() and not capsys.readouterr().err
    # ... and says so when the suffix names another format (a new-user audit: SVG went into
    # a .csv without a word)
    svg = tmp_path / 'segs2.csv'
    assert main(['export', str(src), '-o', str(svg), '--format', 'svg', '-q']) == 0
    assert svg.read_text().startswith('<') and capsys.readouterr().err == (
        f'polyline-mapper: warning: writing svg into {svg}, whose extension says csv '
        '(--format svg decides)\n')


def test_export_and_plot_errors_are_one_line(fitted, tmp_path, capsys):
    _, src, _ = fitted
    cases = [
        ['export', str(src), '-o', str(tmp_path / 'x.dxf')],
        ['export', str(tmp_path / 'missing.json'), '-o', str(tmp_path / 'x.csv')],
        ['plot', str(src), '-o', str(tmp_path / 'x.png'), '--points',
         str(tmp_path / 'missing.npy')],
    ]
    broken = tmp_path / 'broken.json'
    broken.write_text('{"frame_id": "map", "segments": [[1, 2, 3]], "polylines": []}')
    cases.append(['export', str(broken), '-o', str(tmp_path / 'x.svg')])
    for argv in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith('polyline-mapper: error:'), (argv, err)
    assert not list(tmp_path.glob('x.*'))


def _edited(src, tmp_path, edit):
    """Write the map at ``src`` changed by ``edit`` (a function of its JSON dict); its path."""
    data = json.loads(src.read_text())
    edit(data)
    path = tmp_path / 'edited.json'
    path.write_text(json.dumps(data))
    return path


def _move_vertex(data):
    data['polylines'][0][1][0] += 0.05              # a vertex 5 cm off its segments' ends


def _drop_polyline(data):
    del data['polylines'][-1], data['closed'][-1]


@pytest.mark.parametrize('edit, words', [
    (_move_vertex, r'"polylines" disagree with "segments": segment \d+ \(.*\) is no polyline '
                   r'edge \(within 1 mm\)'),
    (_drop_polyline, r'"polylines" disagree with "segments": \d+ polyline edges for \d+ '
                     r'segments'),
])
def test_a_map_whose_polylines_disagree_with_its_segments_is_refused(fitted, tmp_path, capsys,
                                                                     edit, words):
    # GeoJSON and SVG draw the polylines, CSV and the planner grid the segments: a hand-edited
    # map exported to GeoJSON and to CSV showed two different maps, with exit 0.
    _, src, _ = fitted
    bad = _edited(src, tmp_path, edit)
    with pytest.raises(ValueError, match=f'^{re.escape(str(bad))}: {words}'):
        read_map(str(bad))
    for fmt in ('geojson', 'svg', 'csv', 'yaml'):
        assert main(['export', str(bad), '-o', str(tmp_path / f'x.{fmt}')]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and re.match(f'polyline-mapper: error: {re.escape(str(bad))}: '
                                          f'{words}', err[0]), err
    assert not list(tmp_path.glob('x.*'))


def test_polylines_in_another_order_direction_and_rounding_still_read(fitted, tmp_path):
    # Only the geometry must agree: polylines listed backwards, each walked the other way
    # (a closed one from another vertex) and rounded to the millimetre read as the same map.
    _, src, data = fitted

    def shuffle(d):
        polys = [np.round(np.array(p)[::-1], 3) for p in d['polylines']]
        polys = [np.roll(p, 1, axis=0) if c else p for p, c in zip(polys, d['closed'])]
        d['polylines'] = [p.tolist() for p in polys[::-1]]
        d['closed'] = d['closed'][::-1]

    back = read_map(str(_edited(src, tmp_path, shuffle)))
    np.testing.assert_array_equal(back.value.segments, data.value.segments)
    assert back['closed'] == data['closed'][::-1]


def test_plot_map_alone_and_over_points(fitted, tmp_path, capsys):
    folder, src, data = fitted
    alone, over = tmp_path / 'alone.png', tmp_path / 'over.png'
    assert main(['plot', str(src), '-o', str(alone)]) == 0
    assert capsys.readouterr().out.strip() == f'wrote {alone}: {len(data["segments"])} segments'
    assert main(['plot', str(src), '-o', str(over), '--points', str(folder / 'pts.npy')]) == 0
    assert 'over 3300 points' in capsys.readouterr().out
    for png in (alone, over):
        assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert over.stat().st_size > alone.stat().st_size


def test_the_trajectory_exports_as_csv_and_tum(tmp_path, capsys):
    out = tmp_path / 'map.json'
    assert main(['replay', 'sim:corridors', '-o', str(out), '-q']) == 0
    data = read_map(str(out))
    traj = data.value.trajectory
    assert traj is not None and len(traj) == data['stats']['scans_used']
    assert main(['export', str(out), '--trajectory', '-o', str(tmp_path / 't.csv')]) == 0
    rows = list(csv.DictReader(io.StringIO((tmp_path / 't.csv').read_text())))
    got = np.array([[float(r[k]) for k in ('t', 'x', 'y', 'yaw')] for r in rows])
    assert np.allclose(got, traj, atol=1e-4)
    assert main(['export', str(out), '-o', str(tmp_path / 't.tum')]) == 0    # .tum: trajectory
    tum = np.loadtxt(tmp_path / 't.tum')
    assert tum.shape == (len(traj), 8) and np.allclose(tum[:, :3], traj[:, :3], atol=1e-4)
    assert np.allclose(tum[:, 3:6], 0.0)
    yaw = 2 * np.arctan2(tum[:, 6], tum[:, 7])
    assert np.allclose(np.angle(np.exp(1j * (yaw - traj[:, 3]))), 0.0, atol=1e-5)
    assert np.allclose(np.hypot(tum[:, 6], tum[:, 7]), 1.0, atol=1e-5)
    assert 'warning' not in capsys.readouterr().err
    # A recording whose clock went back (a bag played twice): the rows are written as mapped,
    # and a warning says how many are not after the one before (it was silent; an audit).
    twice = json.loads(out.read_text())
    t = twice['trajectory']
    twice['trajectory'] = t + [[row[0] - 5.0] + row[1:] for row in t[:10]]
    twice_path = tmp_path / 'twice.json'
    twice_path.write_text(json.dumps(twice))
    assert main(['export', str(twice_path), '-o', str(tmp_path / 'twice.tum')]) == 0
    err = capsys.readouterr().err
    assert f'twice.tum: 10 of the {len(t) + 10} poses are stamped at or before an' in err, err
    # A map without a trajectory (a batch fit) and a format that cannot hold one: one line.
    assert main(['fit', 'sim:corridors', '-o', str(tmp_path / 'fit.json'), '-q']) == 0
    assert main(['export', str(tmp_path / 'fit.json'), '--trajectory', '-o',
                 str(tmp_path / 'f.csv')]) == 2
    assert main(['export', str(out), '--trajectory', '-o', str(tmp_path / 't.svg')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and 'no trajectory' in err[0] and 'unknown trajectory format' in err[1]
    assert not (tmp_path / 'f.csv').exists() and not (tmp_path / 't.svg').exists()


def test_every_polyline_colour_stands_out_from_the_grey_points():
    # tab10's eighth colour is grey (0.50): every tenth polyline vanished on the grey points
    # (0.55), e.g. a 13 m outer wall of a simulated TurtleBot map (bag audit).
    from polyline_mapper.plot import polyline_colours
    colours = np.array(polyline_colours(20))[:, :3]
    chroma = colours.max(axis=1) - colours.min(axis=1)
    assert chroma.min() > 0.2, colours[chroma.argmin()]         # tab:brown 0.25, grey 0
    assert len({tuple(c) for c in colours[:9]}) == 9        # nine colours before they repeat
