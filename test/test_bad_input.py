"""Bad input: clear ValueErrors from the core, exit code 2 and one line from the CLI, no output."""

import gzip
import os
import subprocess
import sys

import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.core import fit, SMEMSFConfig
import pytest


@pytest.mark.parametrize('pts, why', [
    (np.zeros((0, 2)), 'at least 2 points'),
    (np.ones((1, 2)), 'at least 2 points'),
    (np.ones((50, 2)), 'identical'),
    (np.array([[0.0, 0.0], [1.0, np.nan], [2.0, 0.0]]), 'NaN'),
    (np.array([[0.0, 0.0], [np.inf, 1.0]]), 'NaN or inf'),
    (np.zeros((10, 3)), 'shape'),
    (np.zeros(10), 'shape'),
])
def test_fit_rejects_bad_points(pts, why):
    with pytest.raises(ValueError, match=why):
        fit(pts)


@pytest.mark.parametrize('weights, why', [
    # (names no argument before: "could not convert string to float: 'a'" - an API audit)
    (['a', 'b', 'c'], r'weights must be 3 finite values >= 0; a list of them does not convert'),
    ({'a': 1}, r'weights must be 3 finite values >= 0; a dict of them does not convert'),
    ([1.0, 2.0], r'weights must be 3 finite values >= 0$'),
    ([1.0, -1.0, 1.0], r'weights must be 3 finite values >= 0$'),
])
def test_fit_rejects_bad_weights_naming_them(weights, why):
    with pytest.raises(ValueError, match=why):
        fit(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.1]]), weights=weights)


@pytest.mark.parametrize('kwargs, why', [
    ({'kappa': 0}, 'kappa'), ({'sigma': -1.0}, 'sigma'), ({'shrink_fast': 1.5}, 'shrink_fast'),
    ({'shrink_fast': 0.9, 'shrink_slow': 0.7}, 'shrink_fast'), ({'init': 'magic'}, 'init'),
    ({'max_iterations': 0}, 'max_iterations'), ({'min_support': 1}, 'min_support'),
    ({'r_over_sigma': float('nan')}, 'r_over_sigma'),
    # (a TypeError from np.isfinite, and True taken as 1: an audit)
    ({'sigma': 'abc'}, "sigma must be None or a finite number > 0, got 'abc'"),
    ({'kappa': True}, 'kappa must be a finite number > 0, got True'),
    # Outside the ranges the node's parameters hold to, or not numbers: raw errors later in
    # the fit, or no segment without a word (an API audit)
    ({'tail_fraction': 'x'}, r"tail_fraction must be a finite number in \[0.0, 1.0\], got 'x'"),
    ({'tail_fraction': 2}, 'tail_fraction must be a finite number in'),
    ({'min_support': float('nan')}, 'min_support must be a finite number in'),
    ({'seed': -1}, r'seed must be an integer in \[0, 2147483647\], got -1'),
    ({'seed': 1.5}, 'seed must be an integer'), ({'kappa': 1e300}, 'kappa must be a finite'),
    ({'r_over_sigma': 1e-300}, r'r_over_sigma must be a finite number in \[0.1, 100.0\]'),
    ({'shrink_fast': 'x'}, 'shrink_fast must be a finite number'),
    ({'max_iterations': 'x'}, 'max_iterations must be an integer'),
    ({'sigma': 11.0}, 'sigma must be at most 10 m, got 11.0'),
])
def test_config_rejects_bad_values_with_reason(kwargs, why):
    with pytest.raises(ValueError, match=why):
        SMEMSFConfig(**kwargs)


@pytest.mark.parametrize('kwargs, why', [
    ({'buffer_scans': 1e300}, r'buffer_scans must be an integer in \[1, 1000\], got 1e\+300'),
    ({'margin': 'x'}, r"margin must be a finite number in \[0.0, 100.0\], got 'x'"),
    ({'cell': 1e9}, 'cell must be a finite number in'),
    ({'virtual_cap': 0.0}, r'virtual_cap must be a finite number in \[1e-09, 1000000.0\], '
     r'got 0.0'),
    ({'max_mapping_range': 0}, r'max_mapping_range must be a finite number in \[1e-09, '
     r'1000000.0\], got 0'),
])
def test_the_incremental_config_rejects_bad_values_with_reason(kwargs, why):
    from polyline_mapper.core.incremental import IncrementalConfig
    with pytest.raises(ValueError, match=why):
        IncrementalConfig(**kwargs)
    # whole floats (a YAML file's 20.0) are taken as integers
    assert IncrementalConfig(buffer_scans=3.0).buffer_scans == 3
    assert type(SMEMSFConfig(max_iterations=2e1).max_iterations) is int


def test_a_loaded_maps_noise_scale_is_a_number_numpy_or_not():
    # load(sigma=True) set sigma to 1 m; load(sigma=np.float32(0.01)) was refused as not a
    # finite number (an audit).
    from polyline_mapper.core.incremental import IncrementalMapper
    wall = np.array([[[0.0, 0.0], [1.0, 0.0]]])
    with pytest.raises(ValueError, match='sigma must be a finite number > 0'):
        IncrementalMapper().load(wall, [10.0], sigma=True)
    mapper = IncrementalMapper()
    mapper.load(wall, [10.0], sigma=np.float32(0.01))
    assert mapper.sigma == pytest.approx(0.01)
    assert SMEMSFConfig(sigma=np.float32(0.01)).sigma == pytest.approx(0.01)


def test_a_configuration_or_an_argument_of_the_wrong_type_is_named():
    # An API audit: fit(points, {'sigma': 0.01}) failed on "'dict' object has no attribute
    # 'seed'", IncrementalMapper(SMEMSFConfig()) on "... no attribute 'resolved'", and fit's
    # free_space_window='x' in a comparison deep inside.
    from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper
    from polyline_mapper.session import MappingSession
    pts = np.random.default_rng(0).normal(size=(100, 2))
    for call, words in (
            (lambda: fit(pts, {'sigma': 0.01}), 'config must be of type SMEMSFConfig'),
            (lambda: IncrementalMapper(SMEMSFConfig()),
             'config must be of type IncrementalConfig'),
            (lambda: MappingSession(SMEMSFConfig()), 'config must be of type IncrementalConfig'),
            (lambda: MappingSession(options={}), 'options must be of type SessionOptions'),
            (lambda: fit(pts, free_space_window='x'), 'free_space_window must be an integer'),
            (lambda: fit(pts, free_space_window=2.5), 'free_space_window must be an integer'),
            (lambda: fit(pts, free_space_hit_margin='x'), 'free_space_hit_margin must be')):
        with pytest.raises(TypeError) as caught:
            call()
        assert str(caught.value).startswith(words), caught.value
    assert IncrementalMapper(IncrementalConfig(noise_updates=2)).config.noise_updates == 2


def test_a_map_the_reader_would_refuse_is_not_written(tmp_path):
    # An API audit: write_map wrote a MapValue with a segment and no polylines, which read_map
    # then refused; write_map(FitResult) failed on "no attribute 'items'".
    from polyline_mapper.core.mapvalue import MapValue
    from polyline_mapper.formats.mapjson import read_map, write_map
    out = tmp_path / 'm.json'
    with pytest.raises(ValueError, match='"polylines" disagree with "segments"'):
        write_map(out, MapValue(np.array([[[0.0, 0.0], [1.0, 0.0]]]), [1.0], [], []))
    assert not out.exists()
    result = fit(np.c_[np.linspace(0.0, 2.0, 200), np.zeros(200)])
    with pytest.raises(TypeError, match=r'got FitResult \(MapValue.from_fit\(result\) makes one'):
        write_map(out, result)
    write_map(out, MapValue.from_fit(result))
    assert len(read_map(out).value) == len(result.segments) == 1
    with pytest.raises(ValueError, match=r'segments must be \(K, 2, 2\) or \(K, 4\)'):
        MapValue(np.zeros((3, 3)), [], [], [])
    with pytest.raises(ValueError, match='segments contains NaN or inf'):    # (as trajectory)
        MapValue(np.array([[[0.0, 0.0], [np.nan, 0.0]]]), [1.0], [], [])
    with pytest.raises(ValueError, match=r'trajectory must be \(P, 4\)'):
        MapValue(np.zeros((0, 2, 2)), [], [], [], trajectory=np.zeros((3, 3)))


def test_core_and_simulator_arguments_beyond_use_are_one_line_errors():
    # An API audit: these gave an IndexError / AxisError, a grid 4.6e17 m away, minutes of
    # work or gigabytes asked for, NaN ranges, or a silent skip the session calls an error.
    from polyline_mapper.core import assemble_polylines, IncrementalMapper, map_metrics
    from polyline_mapper.core.grid import rasterise
    from polyline_mapper.core.register import match_scan
    from polyline_mapper.sim import LaserSpec, office_floor, simulate_drive
    segs = np.array([[[0.0, 0.0], [4.0, 0.0]], [[4.0, 0.0], [4.0, 3.0]]])
    pts = np.c_[np.linspace(0.0, 4.0, 50), np.zeros(50)]
    nan = np.full((1, 2, 2), np.nan)
    world = office_floor()
    angles, ranges = np.linspace(-1.0, 1.0, 100), np.full(100, 2.0)
    for call, words in (
            (lambda: map_metrics(pts, segs.reshape(1, 4, 2)), 'segments must have shape'),
            (lambda: map_metrics(pts, nan), 'segments contains NaN or inf'),
            (lambda: assemble_polylines(segs.reshape(1, 4, 2), 0.05), 'segments must have'),
            (lambda: rasterise(nan, 0.05), 'segments contains NaN or inf'),
            (lambda: match_scan(pts, (0, 0, 0), segs, 0.01, spacing=0), 'spacing must be'),
            (lambda: match_scan(pts, (0, 0, 0), segs, 0.01, spacing=1e-7), 'more than 1e+07'),
            (lambda: IncrementalMapper().update_scan(ranges, angles, (0, 0, 0), range_min=5.0,
                                                     range_max=1.0), 'range_min and range_max'),
            (lambda: simulate_drive(world, step=0), 'step must be a number > 0'),
            (lambda: simulate_drive(world, step=1e-9), 'more than 1e+06'),
            (lambda: simulate_drive(world, rate=0), 'rate must be a number > 0'),
            (lambda: simulate_drive(world, waypoints=[]), 'waypoints must be at least 2'),
            (lambda: LaserSpec(noise=float('nan')), 'need noise >= 0')):
        with pytest.raises(ValueError) as caught:
            call()
        assert words in str(caught.value) and '\n' not in str(caught.value), caught.value
    # the forms they take still work: (K, 4) segments, lists, an empty point list
    assert map_metrics(pts, segs.reshape(-1, 4).tolist())['coverage_0_10m'] == 1.0
    assert len(assemble_polylines(segs.reshape(-1, 4), 0.05).polylines) == 1
    assert IncrementalMapper().update([]).skipped == 'no valid points'


def test_unknown_config_key_named():
    with pytest.raises(ValueError, match='sigmaa'):
        SMEMSFConfig.from_dict({'sigmaa': 0.1})


def run_cli(args, tmp_path, capsys):
    out = tmp_path / 'out' / 'map.json'
    png = tmp_path / 'out' / 'map.png'
    code = main(['fit', *args, '-o', str(out), '--plot', str(png), '-q'])
    err = capsys.readouterr().err.strip()
    return code, err, out, png


def write(tmp_path, name, data, mode='w'):
    p = tmp_path / name
    with open(p, mode) as fh:
        fh.write(data)
    return str(p)


@pytest.mark.parametrize('name, content, why', [
    ('nan.csv', 'x,y\n0,0\n1,nan\n2,0\n', 'NaN'),
    ('empty.txt', '', 'usable|points|shape|empty'),
    ('one.txt', '1.0 2.0\n', 'at least 2'),
    ('same.txt', '1 1\n' * 20, 'identical'),
    ('three.csv', '1,2,3\n4,5,6\n', 'shape'),
    ('words.txt', 'hello world\nfoo bar\n', 'unreadable|shape|numeric'),
    ('no_laser.log', 'ODOM 1 2 3 0 0 0 1.0 host 1.0\n', 'no usable FLASER'),
    ('bad_flaser.log', 'FLASER 180 1 2 3\n', 'no usable FLASER'),
    ('unknown.xyz', '1 2\n', 'unknown input type'),
])
def test_cli_bad_files_exit_2_one_line_no_output(tmp_path, capsys, name, content, why):
    path = write(tmp_path, name, content)
    code, err, out, png = run_cli([path], tmp_path, capsys)
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith('polyline-mapper: error:')
    import re
    assert re.search(why, err), err
    assert not out.exists() and not png.exists()
    assert list(tmp_path.glob('out/*')) == []           # no partial or temporary file


def test_cli_truncated_gzip_log(tmp_path, capsys):
    line = 'FLASER 4 1.0 1.0 1.0 1.0 0 0 0 0 0 0 1.0 host 1.0\n' * 200
    blob = gzip.compress(line.encode())
    path = write(tmp_path, 'cut.log.gz', blob[: len(blob) // 2], mode='wb')
    code, err, out, _ = run_cli([path], tmp_path, capsys)
    assert code == 2 and 'truncated' in err and not out.exists()


def test_cli_missing_file_and_bad_config(tmp_path, capsys):
    code, err, out, _ = run_cli([str(tmp_path / 'nope.npy')], tmp_path, capsys)
    assert code == 2 and 'no such file' in err
    pts = tmp_path / 'ok.npy'
    np.save(pts, np.random.default_rng(0).uniform(0, 1, (100, 2)))
    cfg = write(tmp_path, 'cfg.yaml', 'kappa: -3\n')
    code, err, out, _ = run_cli([str(pts), '--config', cfg], tmp_path, capsys)
    assert code == 2 and 'kappa' in err and not out.exists()
    code, err, out, _ = run_cli([str(pts), '--set', 'nonsense=1'], tmp_path, capsys)
    assert code == 2 and 'nonsense' in err


def test_cli_no_traceback_as_a_process(tmp_path):
    """The installed console script prints no traceback on bad input."""
    bad = write(tmp_path, 'bad.csv', '0,0\nnan,1\n')
    proc = subprocess.run([sys.executable, '-m', 'polyline_mapper.cli', 'fit', bad, '-o',
                           str(tmp_path / 'm.json')], capture_output=True, text=True,
                          env={**os.environ, 'PYTHONWARNINGS': 'ignore'})
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr and proc.stderr.count('\n') == 1


def test_cli_refuses_an_empty_frame_id_a_map_could_not_be_read_with(tmp_path, capsys):
    pts = tmp_path / 'ok.npy'
    np.save(pts, np.random.default_rng(0).uniform(0, 1, (100, 2)))
    for frame in ('', ' '):
        code, err, out, _ = run_cli([str(pts), '--frame-id', frame], tmp_path, capsys)
        assert code == 2 and 'must name a frame' in err and not out.exists()
    # nor one the node refuses (a new-user audit: '/map' was written into the map; tf2 refuses
    # frame names with a leading slash)
    code, err, out, _ = run_cli([str(pts), '--frame-id', '/map'], tmp_path, capsys)
    assert code == 2 and "must not start with '/'" in err and "give 'map'" in err
    assert not out.exists()
    assert main(['replay', 'sim:office', '--fixed-frame', '/map', '-o', str(out)]) == 2
    assert "must not start with '/'" in capsys.readouterr().err and not out.exists()


def test_a_csv_with_a_byte_order_mark_keeps_its_first_point(tmp_path):
    # Spreadsheets write a UTF-8 byte-order mark: it made the first line a "header", and its
    # point was dropped without a word.
    from polyline_mapper.formats.points import read_points
    rows = '0,0\n1,0\n2,0.01\n3,0\n'
    plain = write(tmp_path, 'plain.csv', rows)
    bom = write(tmp_path, 'bom.csv', b'\xef\xbb\xbf' + rows.encode(), mode='wb')
    header = write(tmp_path, 'header.csv', b'\xef\xbb\xbfx,y\n' + rows.encode(), mode='wb')
    for path in (plain, bom, header):
        assert np.array_equal(read_points(path), [[0, 0], [1, 0], [2, 0.01], [3, 0]]), path


@pytest.mark.parametrize('name, content, words', [
    # the bad value on line 5 of the file: after a header, a comment and an empty line
    ('header.csv', b'x,y\n0,0\n# a comment\n\n1,abc\n2,0\n',
     "line 5, column 2: 'abc' is not a number"),
    ('bom_crlf.csv', b'\xef\xbb\xbfx,y\r\n0,0\r\n1,1\r\n2,1_0\r\n',
     "line 4, column 2: '1_0' is not a number"),
    ('plain.csv', b'0,0\n1,1\nthree,3\n', "line 3, column 1: 'three' is not a number"),
    ('comment.txt', b'# x y\n0 0\n1 1 # fine\n\n2 oops\n',
     "line 5, column 2: 'oops' is not a number"),
    ('columns.csv', b'x,y\n0,0\n1,1\n2,2,2\n', 'line 4 has 3 column(s) where line 2 has 2'),
    ('short.csv', b'# scan 1\n0,0\n1\n', 'line 3 has 1 column(s) where line 2 has 2'),
    # lines of nothing but whitespace are blank lines, and counted
    ('spaces.csv', b'x,y\n0,0\n   \n\t\n  # note\n1,abc\n',
     "line 6, column 2: 'abc' is not a number"),
    ('spaces_columns.csv', b'  \n0,0\n \t \n1,1,1\n', 'line 4 has 3 column(s) where line 2 has 2'),
    ('spaces.txt', b'0 0\n   \n\t\n2 oops\n', "line 4, column 2: 'oops' is not a number"),
])
def test_a_bad_point_file_line_is_named_as_an_editor_counts(tmp_path, capsys, name, content,
                                                            words):
    # np.loadtxt names the row among the rows it read, from 0 (from 1 for a changed number
    # of columns), blind to the header and comments: 'abc' on line 5 was "row 1".
    from polyline_mapper.formats.points import read_points
    path = write(tmp_path, name, content, mode='wb')
    with pytest.raises(ValueError) as exc:
        read_points(path)
    assert str(exc.value) == f'{path}: unreadable point file ({words})'
    code, err, out, _ = run_cli([path], tmp_path, capsys)
    assert code == 2 and err == f'polyline-mapper: error: {exc.value}' and not out.exists()


@pytest.mark.parametrize('name, content, words', [
    ('nan.csv', b'x,y\n0,0\n# a comment\n\n1,nan\n2,inf\n',
     '2 point(s) NaN, inf or beyond +-1e+08 m; the first on line 5: (1, nan) is NaN or inf'),
    ('far.txt', b'0 0\n1 1\n2 3e9\n', 'the first on line 3: (2, 3e+09) is beyond +-1e+08 m'),
    ('spaces_nan.csv', b'x,y\n   \n0,0\n  # a comment\n\t\n1,nan\n',
     '1 point(s) NaN, inf or beyond +-1e+08 m; the first on line 6: (1, nan) is NaN or inf'),
])
def test_a_point_not_finite_or_too_far_is_named_by_its_file_line(tmp_path, name, content,
                                                                 words):
    # (it was "first at row 1": the row among those numpy read, counted from 0)
    from polyline_mapper.formats.points import read_points
    path = write(tmp_path, name, content, mode='wb')
    with pytest.raises(ValueError) as exc:
        read_points(path)
    assert str(exc.value).startswith(f'{path}: ') and words in str(exc.value), exc.value


@pytest.mark.parametrize('name, content', [
    ('trailing.csv', b'x,y\n0,0\n1,0\n2,0.01\n3,0\n   '),
    ('inside.csv', b'0,0\n   \n1,0\n\t\n2,0.01\n \t \n3,0\n'),
    ('comment.csv', b'x,y\n  # first scan\n0,0\n1,0\n\t# second\n2,0.01\n3,0\n'),
    ('crlf.csv', b'\xef\xbb\xbfx,y\r\n0,0\r\n  \r\n1,0\r\n2,0.01\r\n3,0\r\n  \r\n'),
    ('trailing.txt', b'0 0\n1 0\n   \n2 0.01\n3 0\n \t '),
])
def test_a_line_of_nothing_but_whitespace_is_a_blank_line(tmp_path, capsys, name, content):
    # An empty line was skipped, a line of spaces (an editor's trailing "   ") refused: "line 6
    # has 1 column(s) where line 2 has 2".
    from polyline_mapper.formats.points import read_points
    path = write(tmp_path, name, content, mode='wb')
    assert np.array_equal(read_points(path), [[0, 0], [1, 0], [2, 0.01], [3, 0]])
    code, err, out, _ = run_cli([path], tmp_path, capsys)
    assert code == 0 and out.exists(), err


def test_an_output_named_as_another_format_is_refused(tmp_path, capsys):
    # fit -o map.png wrote JSON into map.png, plot -o map.svg a PNG; a name that says no
    # format (map.out, map) is taken as given.
    pts = tmp_path / 'ok.npy'
    np.save(pts, np.random.default_rng(0).uniform(0, 1, (100, 2)))
    for argv, needle in ((['fit', str(pts), '-o', str(tmp_path / 'm.png')], 'not .png'),
                         (['fit', str(pts), '-o', str(tmp_path / 'm.json'), '--plot',
                           str(tmp_path / 'm.txt')], 'the plot is a PNG image, not .txt')):
        assert main(argv + ['-q']) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0], err
    assert not list(tmp_path.glob('m.*'))
    assert main(['fit', str(pts), '-o', str(tmp_path / 'm.out'), '-q']) == 0
    fitted = tmp_path / 'm.out'
    assert main(['plot', str(fitted), '-o', str(tmp_path / 'm.svg'), '-q']) == 2
    assert 'the plot is a PNG image, not .svg' in capsys.readouterr().err


def test_recording_options_that_would_change_nothing_are_refused(tmp_path, capsys):
    # A point file has no poses and a CARMEN log's fit uses its corrected laser poses:
    # --pose-source, --laser-mount, --scan-topic ... were accepted and ignored.
    pts = tmp_path / 'ok.npy'
    np.save(pts, np.random.default_rng(0).uniform(0, 1, (100, 2)))
    log = write(tmp_path, 'room.log', 'FLASER 4 1.0 1.0 1.0 1.0 0 0 0 0 0 0 1.0 host 1.0\n' * 20)
    for path, extra, needle in (
            (str(pts), ['--laser-mount', '1,2,0'], '--laser-mount does not apply to a point file'),
            (log, ['--pose-source', 'odom', '--scan-topic', '/x'],
             '--pose-source and --scan-topic do not apply to a CARMEN log'),
            # (a review of 2026-12-02: --chord-knots was ignored on a log or a point file)
            (log, ['--chord-knots', 'arc'], '--chord-knots does not apply to a CARMEN log'),
            (str(pts), ['--chord-knots', 'median'], '--chord-knots does not apply to a point')):
        code, err, out, _ = run_cli([path, *extra], tmp_path, capsys)
        assert code == 2 and needle in err and not out.exists(), err
    # fit has no --scan-matching: its advice is the option it has
    code, err, out, _ = run_cli(['sim:office', '--chord-knots', 'arc'], tmp_path, capsys)
    assert code == 2 and err.endswith('--chord-knots applies to scan matching only: add '
                                      '--pose-source scan') and not out.exists(), err


def test_a_log_skips_bad_records_with_reasons_a_person_reads(tmp_path):
    # A pose beyond 1e8 m made fit refuse the whole log (replay skipped the scan); a record
    # with a non-integer count or too few fields was skipped with Python's own words.
    from polyline_mapper.formats.carmen import read_carmen
    good = 'FLASER 4 1.0 1.0 1.0 1.0 {x} 0 0 0 0 0 1.0 host 1.0\n'
    text = (good.format(x=0) * 5 + good.format(x='1e12')
            + 'FLASER 4.5 1.0 1.0 1.0 1.0 0 0 0 0 0 0 1.0 host 1.0\n' + 'ROBOTLASER1 0 1\n'
            + good.format(x=0) * 5)
    log = read_carmen(write(tmp_path, 'bad.log', text))
    assert len(log.records) == 10 and log.skipped == 3
    assert log.skipped_examples == [
        'line 6: pose beyond +-1e+08 m',
        'line 7: FLASER record has a field that is not a number (invalid literal for int() '
        "with base 10: '4.5')",
        'line 8: ROBOTLASER1 record is shorter than its counts say']


@pytest.mark.parametrize('count', [3, 1])
def test_a_flaser_count_below_its_readings_is_a_malformed_record(tmp_path, count):
    """A FLASER whose count is lower than its readings is skipped, not read as other fields."""
    # FLASER n holds n readings, the laser pose, the odometry pose and 1-3 times: with a count
    # too low the next readings were taken for the pose and the time (a map of nonsense and
    # 'log times do not increase'); a count too high was already refused.
    from polyline_mapper.formats.carmen import read_carmen
    good = 'FLASER 4 1.0 1.0 1.0 1.0 0 0 0 0 0 0 1.0 host 1.0\n'
    short = good.replace('FLASER 4 ', f'FLASER {count} ')
    bare = 'FLASER 4 1.0 1.0 1.0 1.0 0 0 0 0 0 0 1.0\n'       # no host, no logger time
    log = read_carmen(write(tmp_path, 'count.log', good * 3 + short + bare + good))
    assert len(log.records) == 5 and log.skipped == 1
    assert log.skipped_examples == [
        f'line 4: FLASER announces {count} readings but the line has 15 fields']


@pytest.mark.parametrize('glitch, every', [('100.0', 0), ('1e300', 0), ('1e300', 1)])
def test_one_glitched_reading_does_not_hide_the_no_return_code(tmp_path, glitch, every):
    """A single reading above a log's no-return code leaves the no-returns dropped."""
    # every: the glitch in every record (a new-user audit: 1e300 repeated was taken for the
    # code, and the 81 m no-returns became points, mean distance 3.7 -> 120 cm); no laser
    # measures 1000 m, so such readings are no-returns and never the code.
    # The code was the largest reading when it occurred more than once: one glitch above it
    # (a corrupt reading) made the log have none, and every 81.83 m no-return became a point
    # (Intel: 4172 points 81 m out, mean distance 2.39 -> 8.09 cm, 0.8 -> 21.6 % contradicted;
    # a 1e300 glitch made fit refuse the whole log).
    from polyline_mapper.formats.carmen import read_carmen
    rng = np.random.default_rng(0)
    lines = []
    for i in range(20):
        ranges = np.round(rng.uniform(1.0, 8.0, 180), 2)
        ranges[::9] = 81.83                                   # the no-returns
        if i == 7 or every:
            ranges = ranges.astype(object)
            ranges[50] = glitch
        vals = ' '.join(str(v) for v in ranges)
        lines.append(f'FLASER 180 {vals} {0.1 * i} 0 0 {0.1 * i} 0 0 {i} host {i}\n')
    path = write(tmp_path, 'glitch.log', ''.join(lines))
    log = read_carmen(path)
    assert log.no_return == 81.83
    points = log.points()
    assert len(points) == 20 * 160 - (20 if every else 1) and np.abs(points).max() < 11.0
    out = str(tmp_path / 'map.json')
    assert main(['fit', path, '-o', out, '-q']) == 0
