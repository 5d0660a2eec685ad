"""The planner map in MAP.json and its map_server export (YAML + PGM), parsed back."""

import json
import os

from conftest import saved_office_map
import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.core.grid import FREE, OCCUPIED, UNKNOWN
from polyline_mapper.formats.mapjson import read_map
import pytest
import yaml


@pytest.fixture(scope='module')
def replayed(office_map_file, tmp_path_factory):
    """Replay the simulated office; return the folder and the map JSON path."""
    folder = tmp_path_factory.mktemp('office')
    return folder, saved_office_map(office_map_file, folder)


def read_pgm(path) -> np.ndarray:
    """Parse a binary PGM (P5, maxval 255, comment lines allowed); return its rows, top first."""
    raw = open(path, 'rb').read()
    fields, pos = [], 0
    while len(fields) < 4:
        while raw[pos:pos + 1].isspace():
            pos += 1
        if raw[pos:pos + 1] == b'#':
            pos = raw.index(b'\n', pos) + 1
            continue
        end = pos
        while not raw[end:end + 1].isspace():
            end += 1
        fields.append(raw[pos:end].decode('ascii'))
        pos = end
    pos += 1                                        # the single whitespace before the pixels
    assert fields[0] == 'P5' and fields[3] == '255'
    width, height = int(fields[1]), int(fields[2])
    assert len(raw) - pos == width * height
    return np.frombuffer(raw[pos:], dtype=np.uint8).reshape(height, width)


def load_like_map_server(yaml_path):
    """Load the pair as nav2_map_server does (trinary); return (cells row 0 = lowest y, meta)."""
    meta = yaml.safe_load(open(yaml_path, encoding='utf-8'))
    image = meta['image']
    if not os.path.isabs(image):
        image = os.path.join(os.path.dirname(yaml_path), image)
    shade = read_pgm(image).astype(float) / 255.0
    occ = shade if meta['negate'] else 1.0 - shade
    cells = np.where(occ > meta['occupied_thresh'], OCCUPIED,
                     np.where(occ < meta['free_thresh'], FREE, UNKNOWN))
    return np.flipud(cells), meta


def _distance_to_segments(p, segs):
    a, d = segs[:, 0], segs[:, 1] - segs[:, 0]
    t = np.clip(np.einsum('nkj,kj->nk', p[:, None] - a, d) / np.einsum('kj,kj->k', d, d), 0, 1)
    return np.linalg.norm(p[:, None] - (a + t[..., None] * d), axis=2).min(axis=1)


def test_replay_stores_the_grid_and_the_exported_pair_loads_back_unchanged(replayed):
    folder, src = replayed
    data = read_map(src)
    grid = data.grid
    assert grid is not None and grid.resolution == 0.05
    assert (grid.data == FREE).sum() > 10 * (grid.data == OCCUPIED).sum() > 0
    sub = folder / 'maps'
    sub.mkdir()
    out = sub / 'office.yaml'
    assert main(['export', str(src), '-o', str(out), '-q']) == 0
    cells, meta = load_like_map_server(str(out))
    assert meta['image'] == 'office.pgm' and (sub / 'office.pgm').is_file()
    assert meta['mode'] == 'trinary' and meta['resolution'] == grid.resolution
    assert meta['origin'] == [grid.origin[0], grid.origin[1], 0.0]
    assert np.array_equal(cells, grid.data)        # every cell, through map_server's rule
    # occupied pixels are where the segments are, and every segment is drawn
    segs = data.value.segments
    res = meta['resolution']
    rows, cols = np.nonzero(cells == OCCUPIED)
    centres = np.array(meta['origin'][:2]) + (np.stack([cols, rows], 1) + 0.5) * res
    # (the file rounds segments to 0.1 mm; the grid was drawn before: allow that much)
    assert _distance_to_segments(centres, segs).max() <= res * np.sqrt(0.5) + 1e-4
    t = np.linspace(0, 1, 50)[None, :, None]
    along = (segs[:, None, 0] + t * (segs[:, None, 1] - segs[:, None, 0])).reshape(-1, 2)
    rel = (along - np.array(meta['origin'][:2])) / res
    clear = (np.abs(rel - np.round(rel)) > 2e-3).all(axis=1)      # not within 0.1 mm of a line
    assert clear.mean() > 0.5          # (the simulated walls lie on cell lines)
    px = np.floor(rel[clear]).astype(int)
    assert (cells[px[:, 1], px[:, 0]] == OCCUPIED).all()
    # free space: the office's rooms, not the outside
    free = np.array(meta['origin'][:2]) + (np.stack(np.nonzero(cells.T == FREE), 1) + 0.5) * res
    assert free.min(axis=0)[0] > segs[..., 0].min() - res
    assert free.max(axis=0)[1] < segs[..., 1].max() + res


def test_every_cell_the_files_segments_cross_is_occupied_in_its_grid(replayed):
    # A planner-map audit: the grid was composed from the segments before the file rounded
    # them to 0.1 mm, and 18 cells the office map's stored segments cross were free or
    # unknown in the stored grid (the wall one row over).
    from polyline_mapper.core.grid import GridMap, mark_segments
    saved = read_map(replayed[1])
    grid = saved.grid
    marked = GridMap(grid.data.copy(), grid.resolution, grid.origin)
    mark_segments(marked, saved.value.segments)
    assert np.array_equal(marked.data, grid.data)
    assert (grid.data == OCCUPIED).sum() > 1000


def test_a_map_without_a_grid_exports_its_segments_occupied_and_the_rest_unknown(tmp_path):
    segs = [[0.01, 0.01, 4.01, 0.01], [4.01, 0.01, 4.01, 3.01]]   # off the cell lines
    src = tmp_path / 'old.json'
    src.write_text(json.dumps({'schema_version': 1, 'frame_id': 'map', 'segments': segs,
                               'polylines': [[[0.01, 0.01], [4.01, 0.01], [4.01, 3.01]]],
                               'closed': [False]}))
    assert read_map(src).grid is None
    assert main(['export', str(src), '-o', str(tmp_path / 'old.yaml'), '-q']) == 0
    cells, meta = load_like_map_server(str(tmp_path / 'old.yaml'))
    assert set(np.unique(cells)) == {OCCUPIED, UNKNOWN}
    assert meta['resolution'] == 0.05
    origin = np.array(meta['origin'][:2])
    for x, y in ((0.02, 0.01), (2.0, 0.01), (4.01, 1.5), (4.01, 2.99), (4.0, 0.02)):
        c = np.floor((np.array([x, y]) - origin) / 0.05).astype(int)
        assert cells[c[1], c[0]] == OCCUPIED
    assert (cells == OCCUPIED).sum() <= (4 + 3) / 0.05 + 4


def test_a_map_without_a_segment_gives_a_planner_no_free_space(tmp_path, capsys):
    # An export audit: a map saved during the mapper's first updates (the noise scale is
    # estimated over 5, no segment yet) stored its traced free space, 42,393 free cells of the
    # office and no wall, and export wrote it for map_server: free space a planner crosses.
    # The node publishes no grid before its first segment; the files now say the same.
    out = tmp_path / 'few.json'
    assert main(['replay', 'sim:office', '--every', '100', '-o', str(out), '-q']) == 0
    data = json.loads(out.read_text())
    assert data['segments'] == [] and data['stats']['scans_used'] >= 3 and 'grid' not in data
    # An older file with such a grid: read without it, exported with every cell unknown.
    from polyline_mapper.core.grid import GridMap
    from polyline_mapper.formats.mapjson import grid_to_dict
    free = GridMap(np.zeros((40, 60), dtype=np.int8), 0.05, (-1.0, -1.0))
    data['grid'] = grid_to_dict(free)
    old = tmp_path / 'old.json'
    old.write_text(json.dumps(data))
    assert read_map(old).grid is None
    assert main(['export', str(old), '-o', str(tmp_path / 'old.yaml')]) == 0
    assert 'the map has no segment: one unknown cell' in capsys.readouterr().out
    cells, _ = load_like_map_server(str(tmp_path / 'old.yaml'))
    assert cells.tolist() == [[UNKNOWN]]
    # A map with a segment keeps its stored grid, free cells and all.
    data['segments'] = [[0.0, 0.0, 1.0, 0.0]]
    data['polylines'], data['closed'] = [[[0.0, 0.0], [1.0, 0.0]]], [False]
    data.pop('support', None)
    one = tmp_path / 'one.json'
    one.write_text(json.dumps(data))
    assert (read_map(one).grid.data == FREE).sum() == 40 * 60


def test_bad_grid_entries_and_refused_outputs_are_one_line_errors(replayed, tmp_path, capsys):
    _, src = replayed
    good = json.loads(src.read_text())
    bad_entries = {
        'cells': ({'cells': [0, 5]}, 'hold 5 cells'),
        'values': ({'cells': [7] + good['grid']['cells'][1:]}, '-1, 0 or 100'),
        'resolution': ({'resolution': -1.0}, 'resolution'),
        'size': ({'width': 10 ** 6, 'height': 10 ** 6}, 'at most'),
        'origin': ({'origin': [1.0]}, 'origin'),
    }
    for name, (change, message) in bad_entries.items():
        data = dict(good, grid=dict(good['grid'], **change))
        path = tmp_path / f'{name}.json'
        path.write_text(json.dumps(data))
        with pytest.raises(ValueError, match=message):
            read_map(path)
        assert main(['export', str(path), '-o', str(tmp_path / f'{name}.yaml')]) == 2
        err = capsys.readouterr().err
        assert err.startswith('polyline-mapper: error: ') and err.count('\n') == 1
        assert not (tmp_path / f'{name}.yaml').exists() and not (tmp_path / f'{name}.pgm').exists()
    no_grid = dict(good)
    del no_grid['grid']
    (tmp_path / 'plain.json').write_text(json.dumps(no_grid))
    assert read_map(tmp_path / 'plain.json').grid is None
    # the YAML would replace the input: refused, and no PGM is left behind
    before = src.read_bytes()
    assert main(['export', str(src), '-o', str(src), '--format', 'yaml']) == 2
    assert src.read_bytes() == before and not src.with_suffix('.pgm').exists()
    for extra in (['--format', 'yaml'], []):    # (without --format: "unknown format 'pgm'")
        assert main(['export', str(src), '-o', str(tmp_path / 'x.pgm')] + extra) == 2
        assert 'name the map_server YAML' in capsys.readouterr().err
        assert not (tmp_path / 'x.pgm').exists()


def test_a_grid_too_large_for_the_file_is_left_out(replayed, monkeypatch, tmp_path, capsys):
    from polyline_mapper.formats import mapjson
    _, src = replayed
    data = read_map(src)
    monkeypatch.setattr(mapjson, 'MAX_GRID_RUNS', 10)
    out = mapjson.map_value_to_dict(data.value, None, data.grid)
    assert 'grid' not in out and 'more than 10' in out['stats']['grid_omitted']
    # its export says the stored grid was dropped, not only that there is none
    (tmp_path / 'omitted.json').write_text(json.dumps(out))
    assert main(['export', str(tmp_path / 'omitted.json'), '-o', str(tmp_path / 'o.yaml')]) == 0
    said = capsys.readouterr().out
    assert 'no planner map stored (it was too large for the map file: ' in said, said
    # a map without a grid spanning more cells than a grid may hold: one line, nothing written
    far = tmp_path / 'far.json'
    far.write_text(json.dumps({'schema_version': 1, 'frame_id': 'map',
                               'segments': [[0, 0, 1, 0], [9000, 9000, 9001, 9000]],
                               'polylines': [[[0, 0], [1, 0]], [[9000, 9000], [9001, 9000]]],
                               'closed': [False, False]}))
    assert main(['export', str(far), '-o', str(tmp_path / 'far.yaml')]) == 2
    assert 'too large for a grid export' in capsys.readouterr().err
    assert not (tmp_path / 'far.yaml').exists() and not (tmp_path / 'far.pgm').exists()
    # the message names the option that makes it fit: 2 m cells, both segments occupied
    assert main(['export', str(far), '-o', str(tmp_path / 'far.yaml'), '--resolution', '2',
                 '-q']) == 0
    meta = yaml.safe_load((tmp_path / 'far.yaml').read_text())
    pgm = read_pgm(tmp_path / 'far.pgm')
    assert meta['resolution'] == 2.0 and pgm.shape[0] * 2.0 > 9000
    assert (pgm == 0).sum() >= 2                          # occupied, map_saver's black
    # a stored grid keeps its own cell size; other formats have none
    _, src = replayed
    for argv, needle in ((['-o', str(tmp_path / 'r.yaml'), '--resolution', '0.2'],
                          'stores its planner grid at'),
                         (['-o', str(tmp_path / 'r.csv'), '--resolution', '0.2'],
                          'map_server YAML + PGM export only')):
        assert main(['export', str(src), *argv, '-q']) == 2
        assert needle in capsys.readouterr().err


def test_segments_too_long_to_rasterise_are_refused_and_long_ones_marked_in_blocks(
        tmp_path, capsys, monkeypatch):
    # A hand-made map of twenty 1000 km segments a millimetre apart passed every check (its
    # grid, 2e7 x 3 cells, is under the cap) and its export took 6.4 GB before it failed with
    # a traceback (new-user audit): the cells the segments cross are bounded too now.
    from polyline_mapper.core import grid as grid_module
    segs = [[0.0, 0.001 * i, 1e6, 0.001 * i] for i in range(20)]
    many = tmp_path / 'many.json'
    many.write_text(json.dumps({'schema_version': 1, 'frame_id': 'map', 'segments': segs,
                                'polylines': [[s[:2], s[2:]] for s in segs],
                                'closed': [False] * 20}))
    assert main(['export', str(many), '-o', str(tmp_path / 'many.yaml')]) == 2
    err = capsys.readouterr().err
    assert 'the segments cross about 4e+08 cells at 0.05 m' in err and 'Traceback' not in err
    assert not (tmp_path / 'many.yaml').exists() and not (tmp_path / 'many.pgm').exists()
    # marked in blocks (a segment longer than a block in pieces): the same cells as at once
    rng = np.random.default_rng(0)
    walls = rng.uniform(0.0, 30.0, (300, 2, 2))
    walls[:5, 1] = walls[:5, 0] + [25.0, 0.3]
    whole = grid_module.rasterise(walls, 0.05).data
    monkeypatch.setattr(grid_module, 'MARK_BLOCK', 37)
    blocks = grid_module.rasterise(walls, 0.05).data
    assert (whole == OCCUPIED).sum() > 90000 and np.array_equal(whole, blocks)


def test_a_file_name_beyond_the_basic_plane_loads_in_map_server(replayed, tmp_path, capsys):
    # json.dumps escaped an emoji as a surrogate pair ("\ud83d\ude00"), which yaml-cpp (nav2's
    # YAML reader) refuses as invalid Unicode: the name is now written as it is, in UTF-8.
    _, out = replayed
    target = tmp_path / 'maps' / 'floor 2 \U0001F600.yaml'
    target.parent.mkdir()
    assert main(['export', str(out), '-o', str(target), '-q']) == 0
    text = target.read_text(encoding='utf-8')
    assert '\\u' not in text and 'image: "floor 2 \U0001F600.pgm"' in text
    cells, meta = load_like_map_server(target)
    assert np.array_equal(cells, read_map(out).grid.data)
    # A name that is no UTF-8 at all (bytes the file system allows) cannot be written in the
    # YAML: one line, nothing written.
    bad = os.fsdecode(bytes(tmp_path / 'maps') + b'/m\xff.yaml')
    assert main(['export', str(out), '-o', bad, '-q']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'the image name is not valid UTF-8' in err[0], err
    assert sorted(p.name for p in target.parent.iterdir()) == sorted(
        [target.name, target.with_suffix('.pgm').name])


def test_a_yaml_that_is_a_symlink_gets_its_pair_beside_the_target(replayed, tmp_path, capsys):
    # -o here/map.yaml -> ../there/real.yaml wrote the YAML through the link, but here/map.pgm
    # beside the link, named "map.pgm" in the YAML: loading there/real.yaml found no image.
    # map_server takes a relative image relative to the YAML path it is given, unresolved.
    _, src = replayed
    grid = read_map(src).grid.data
    here, there = tmp_path / 'here', tmp_path / 'there'
    here.mkdir()
    there.mkdir()
    (there / 'real.yaml').write_text('image: "old.pgm"\n')
    link = here / 'map.yaml'
    link.symlink_to(os.path.join('..', 'there', 'real.yaml'))
    assert main(['export', str(src), '-o', str(link)]) == 0
    for opened in (link, there / 'real.yaml'):
        cells, _ = load_like_map_server(str(opened))
        assert np.array_equal(cells, grid), opened
    real = os.path.realpath(there)
    assert link.is_symlink() and os.listdir(here) == ['map.yaml']
    assert sorted(os.listdir(there)) == ['real.pgm', 'real.yaml']
    assert yaml.safe_load(link.read_text())['image'] == f'{real}/real.pgm'
    out = capsys.readouterr().out
    assert out.startswith(f'wrote {link} (a link to {real}/real.yaml) and {real}/real.pgm: '
                          'the map_server pair'), out
    # a link beside its target: the bare name, which both find
    current = there / 'current.yaml'
    current.symlink_to('real.yaml')
    assert main(['export', str(src), '-o', str(current), '-q']) == 0
    assert current.is_symlink() and sorted(os.listdir(there)) == [
        'current.yaml', 'real.pgm', 'real.yaml']
    assert yaml.safe_load(current.read_text())['image'] == 'real.pgm'
    for opened in (current, there / 'real.yaml'):
        cells, _ = load_like_map_server(str(opened))
        assert np.array_equal(cells, grid), opened
    # a link to the input is refused, and nothing is written
    to_input = here / 'input.yaml'
    to_input.symlink_to(src)
    before = src.read_bytes()
    assert main(['export', str(src), '-o', str(to_input)]) == 2
    assert 'is an input of this run' in capsys.readouterr().err
    assert src.read_bytes() == before and not src.with_suffix('.pgm').exists()
    assert sorted(os.listdir(here)) == ['input.yaml', 'map.yaml']
