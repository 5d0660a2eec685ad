"""Configuration read through the parameter table: files, ROS 2 parameter files and --set."""

import numpy as np
from polyline_mapper.config import ConfigError, load_fit_config, load_mapper_config, read_values
from polyline_mapper.params import all_params
import pytest


def test_the_shipped_parameter_file_gives_the_defaults(tmp_path):
    from polyline_mapper.core.incremental import IncrementalConfig
    from conftest import REPO
    config = load_mapper_config(str(REPO / 'config' / 'polyline_mapper.yaml'))
    assert config == IncrementalConfig()


def _replayed(main, tmp_path, name, *argv):
    import json
    out = tmp_path / name
    assert main(['replay', *argv, '-o', str(out), '-q']) == 0
    return json.loads(out.read_text())


def test_replay_maps_with_the_node_parameters_of_its_config_file(tmp_path, capsys):
    # A robot's parameter file (odometry, scan matching, arc knots, a laser mount) gave replay
    # only its smemsf block: the rest was named in a warning and the map made with replay's
    # defaults, so the same file mapped one way live and another offline. Replay now takes the
    # node parameters that place and group the scans, as the node does; only the live node's
    # own (outputs, queues, timers) are named, in one line.
    from conftest import REPO
    from polyline_mapper.cli import main
    from polyline_mapper.config import read_node_file
    for name in ('polyline_mapper.yaml', 'lds01.yaml', 'rplidar.yaml', 'free_space.yaml',
                 'no_free_space.yaml'):
        nf = read_node_file(str(REPO / 'config' / name))
        assert (nf.names, nf.live_only, nf.unknown, nf.skipped) == ((),) * 4, name
    path = tmp_path / 'robot.yaml'
    path.write_text('/**:\n  ros__parameters:\n    pose_source: odom\n    scan_matching: true\n'
                    '    chord_knots: arc\n    laser_x: 0.05\n    grid_resolution: 0.1\n'
                    '    fixed_frame: map\n    map_output_path: /nowhere/map.json\n'
                    '    smemsf:\n      sigma: 0.01\n')
    assert read_node_file(str(path)).live_only == ('map_output_path: /nowhere/map.json',)
    drive = 'sim:hall,odom_drift=3'
    filed = _replayed(main, tmp_path, 'file.json', drive, '--config', str(path))
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'not used by replay: map_output_path' in err
    st = filed['stats']
    assert st['node_parameters'] == ['pose_source', 'scan_matching', 'chord_knots',
                                     'grid_resolution', 'laser_x']
    assert (st['pose_source'], st['laser_mount']) == ('odom', '0.05,0,0')
    flags = _replayed(main, tmp_path, 'flags.json', drive, '--pose-source', 'odom',
                      '--scan-matching', '--chord-knots', 'arc', '--laser-mount', '0.05,0,0',
                      '--set', 'sigma=0.01')
    assert filed['segments'] == flags['segments'] and filed['trajectory'] == flags['trajectory']
    # the planner map's resolution has no flag: the node's parameter sets it
    assert (filed['grid']['resolution'], flags['grid']['resolution']) == (0.1, 0.05)
    # a flag on the command line wins over the file
    arc = _replayed(main, tmp_path, 'median.json', drive, '--config', str(path),
                    '--chord-knots', 'median', '--laser-mount', '0,0,0')
    assert 'chord_knots' not in arc['stats']['node_parameters']
    median = _replayed(main, tmp_path, 'median2.json', drive, '--pose-source', 'odom',
                       '--scan-matching', '--laser-mount', '0,0,0', '--set', 'sigma=0.01')
    assert arc['segments'] == median['segments'] and arc['segments'] != filed['segments']


def test_chord_knots_of_a_config_file_without_scan_matching_change_nothing(tmp_path, capsys):
    # The node leaves chord_knots unused without scan matching; so does replay, without the
    # error --chord-knots gets there.
    from polyline_mapper.cli import main
    path = tmp_path / 'knots.yaml'
    path.write_text('/**:\n  ros__parameters:\n    chord_knots: arc\n')
    filed = _replayed(main, tmp_path, 'file.json', 'sim:hall', '--config', str(path))
    plain = _replayed(main, tmp_path, 'plain.json', 'sim:hall')
    assert filed['segments'] == plain['segments']
    assert 'node_parameters' not in filed['stats']
    assert capsys.readouterr().err == ''


def test_fit_names_the_node_parameters_of_its_config_file_it_does_not_use(tmp_path, capsys):
    # fit places a bag's or a drive's scans by its own flags (no scan matching): a robot's
    # file that says odometry and matching would otherwise be followed offline by replay and
    # passed over by fit without a word.
    from polyline_mapper.cli import main
    path = tmp_path / 'robot.yaml'
    path.write_text('/**:\n  ros__parameters:\n    pose_source: odom\n    scan_matching: true\n'
                    '    smemsf:\n      kappa: 3.0\n')
    assert main(['fit', 'sim:hall', '--config', str(path), '-o', str(tmp_path / 'm.json'),
                 '-q']) == 0
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'not used by fit' in err
    assert err.rstrip().endswith(': pose_source, scan_matching')


def test_replay_localizes_on_the_map_its_config_file_names(tmp_path):
    # map_input_path, initial_pose (radians) and mapping false, as the node takes them.
    import math
    from polyline_mapper.cli import main
    drive = 'sim:hall,odom_drift=3'
    saved = tmp_path / 'saved.json'
    _replayed(main, tmp_path, 'saved.json', drive, '--pose-source', 'odom', '--scan-matching')
    first = _replayed(main, tmp_path, 'first.json', 'sim:hall,odom_drift=4',
                      '--pose-source', 'odom', '--scan-matching')['trajectory'][0]
    x, y, yaw = first[1:]
    path = tmp_path / 'loc.yaml'
    path.write_text(f'/**:\n  ros__parameters:\n    pose_source: odom\n'
                    f'    map_input_path: {saved}\n    initial_pose: [{x!r}, {y!r}, {yaw!r}]\n'
                    f'    mapping: false\n')
    filed = _replayed(main, tmp_path, 'file.json', 'sim:hall,odom_drift=4', '--config', str(path))
    flags = _replayed(main, tmp_path, 'flags.json', 'sim:hall,odom_drift=4', '--pose-source',
                      'odom', '--map', str(saved), '--no-mapping', '--initial-pose',
                      f'{x!r},{y!r},{math.degrees(yaw)!r}')
    assert filed['stats']['node_parameters'] == [
        'pose_source', 'map_input_path', 'initial_pose', 'mapping']
    assert filed['stats']['mapping'] is False
    assert filed['segments'] == json_segments(saved)          # localization only: unchanged
    err = np.abs(np.asarray(filed['trajectory']) - np.asarray(flags['trajectory']))
    assert err[:, 1:3].max() < 1e-6 and err[:, 3].max() < 1e-6


def json_segments(path):
    import json
    return json.loads(path.read_text())['segments']


def test_replay_names_typos_other_blocks_and_where_the_node_differs(tmp_path, capsys):
    # A new user's audit: misspelt names were called "live node parameters"; a block for the
    # node under another name was passed over without a word; and a file that leaves
    # fixed_frame and the laser mount at their defaults mapped offline (replay finds the TF
    # tree's root and the mount on /tf_static) where the node, which takes them as they are,
    # skipped every scan ('map') and placed the laser 0.2 m off.
    from polyline_mapper.cli import main
    typo = tmp_path / 'typo.yaml'
    typo.write_text('polyline_mapper_node:\n  ros__parameters:\n    pose_sorce: odom\n'
                    '    use_sim_time: true\n    qos_overrides:\n      /scan:\n'
                    '        subscription:\n          depth: 50\n')
    _replayed(main, tmp_path, 'typo.json', 'sim:hall', '--config', str(typo))
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert 'does not have, not used: pose_sorce (did you mean pose_source?)' in err
    multi = tmp_path / 'multi.yaml'
    multi.write_text('amcl:\n  ros__parameters:\n    x: 1\nmapper:\n  ros__parameters:\n'
                     '    pose_source: odom\n/**:\n  ros__parameters:\n    use_sim_time: true\n')
    _replayed(main, tmp_path, 'multi.json', 'sim:hall', '--config', str(multi))
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'blocks of other nodes not read: /amcl, /mapper' in err
    odom = tmp_path / 'odom.yaml'
    odom.write_text('/**:\n  ros__parameters:\n    pose_source: odom\n')
    replayed = _replayed(main, tmp_path, 'odom.json', 'sim:hall', '--config', str(odom))
    assert replayed['stats']['coverage_0_10m'] > 0.99       # replay: root 'odom', /tf_static
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2
    assert "maps in fixed_frame 'map' (the default), replay found 'odom'" in err[0]
    assert 'laser_x: 0.2, laser_y: 0.0, laser_yaw: 0.0' in err[1]      # doubles, as the node
    # a file of mapper entries only is no robot's file: nothing said of the node's frames
    evidence = tmp_path / 'evidence.yaml'
    evidence.write_text('/**:\n  ros__parameters:\n    incremental:\n'
                        '      free_space_window: 0\n')
    _replayed(main, tmp_path, 'evidence.json', 'sim:hall', '--config', str(evidence))
    assert capsys.readouterr().err == ''
    odom.write_text('/**:\n  ros__parameters:\n    pose_source: odom\n    fixed_frame: odom\n'
                    '    laser_x: 0.2\n')
    same = _replayed(main, tmp_path, 'same.json', 'sim:hall', '--config', str(odom))
    assert capsys.readouterr().err == '' and same['segments'] == replayed['segments']
    # with scan matching the map frame is above the odometry's: the node broadcasts nothing
    odom.write_text(odom.read_text() + '    scan_matching: true\n')
    _replayed(main, tmp_path, 'matched.json', 'sim:hall', '--config', str(odom))
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and "fixed_frame is the odometry's own ('odom')" in err


def test_replay_set_overrides_the_node_parameters_of_its_config_file(tmp_path, capsys):
    # "A flag wins", also where there is no flag: --set takes the node's scalar parameters.
    from polyline_mapper.cli import main
    path = tmp_path / 'sm.yaml'
    path.write_text('/**:\n  ros__parameters:\n    pose_source: odom\n    scan_matching: true\n'
                    '    fixed_frame: odom\n    laser_x: 0.2\n')
    drive = 'sim:hall,odom_drift=3'
    off = _replayed(main, tmp_path, 'off.json', drive, '--config', str(path),
                    '--set', 'scan_matching=false')
    plain = _replayed(main, tmp_path, 'plain.json', drive, '--pose-source', 'odom')
    assert off['segments'] == plain['segments'] and off['trajectory'] == plain['trajectory']
    assert 'scan_matching' not in off['stats']['node_parameters']
    framed = _replayed(main, tmp_path, 'framed.json', drive, '--set', 'pose_source=odom',
                       '--set', 'fixed_frame=odom', '--set', 'grid_resolution=0.1')
    assert framed['frame_id'] == 'odom' and framed['grid']['resolution'] == 0.1
    out = tmp_path / 'bad.json'
    capsys.readouterr()                 # (the unmatched drifted maps are warned of)
    assert main(['replay', drive, '--set', 'scan_matching=maybe', '-o', str(out), '-q']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'scan_matching must be true or false' in err
    assert not out.exists()
    # an odom_frame the scans' tree does not have: no scan is placed (the first one was, from
    # the tree's root, and the replay wrote an empty map with exit code 0)
    assert main(['replay', drive, '--scan-matching', '--set', 'odom_frame=wheel_odom', '-o',
                 str(out), '-q']) == 2
    err = capsys.readouterr().err
    assert "does not reach odom_frame 'wheel_odom'" in err and not out.exists()


def test_replay_refuses_an_integer_where_the_node_takes_a_double(tmp_path, capsys):
    # The node refuses laser_yaw: 1 (a ROS 2 parameter's type is its YAML value's); a file
    # replay took mapped offline and failed to start on the robot.
    from polyline_mapper.cli import main
    for text, name in (('    pose_source: odom\n    laser_yaw: 1\n', 'laser_yaw is 1'),
                       ('    marker_color: [1, 0, 0, 1.0]\n', 'marker_color is [1, 0, 0, 1.0]')):
        path = tmp_path / 'int.yaml'
        path.write_text('/**:\n  ros__parameters:\n' + text)
        out = tmp_path / 'm.json'
        assert main(['replay', 'sim:hall', '--config', str(path), '-o', str(out), '-q']) == 2
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and name in err and 'write' in err and not out.exists()


def test_replay_map_flag_stands_for_the_files_map_input_path(tmp_path, capsys):
    # A localization file (mapping false, an initial pose) with the map given at launch, as
    # the node takes `-p map_input_path:=...`; and a missing map_input_path names the file.
    from polyline_mapper.cli import main
    drive = 'sim:hall,odom_drift=3'
    saved = tmp_path / 'saved.json'
    _replayed(main, tmp_path, 'saved.json', drive, '--pose-source', 'odom', '--scan-matching')
    path = tmp_path / 'loc.yaml'
    path.write_text('/**:\n  ros__parameters:\n    mapping: false\n')
    loc = _replayed(main, tmp_path, 'loc.json', drive, '--pose-source', 'odom', '--config',
                    str(path), '--map', str(saved))
    assert loc['segments'] == json_segments(saved) and loc['stats']['mapping'] is False
    path.write_text('/**:\n  ros__parameters:\n    map_input_path: nowhere.json\n')
    out = tmp_path / 'm.json'
    capsys.readouterr()
    assert main(['replay', drive, '--config', str(path), '-o', str(out), '-q']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'loc.yaml: map_input_path: nowhere.json' in err


def test_a_node_parameter_the_node_refuses_is_refused_by_replay_in_one_line(tmp_path, capsys):
    from polyline_mapper.cli import main
    path = tmp_path / 'bad.yaml'
    path.write_text('/**:\n  ros__parameters:\n    initial_pose: [1.0, 0.0, 0.0]\n')
    out = tmp_path / 'map.json'
    assert main(['replay', 'sim:hall', '--config', str(path), '-o', str(out), '-q']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'bad.yaml: initial_pose' in err and 'map_input_path' in err
    assert not out.exists()


def test_dotted_nested_and_plain_keys_of_a_ros_parameter_file(tmp_path):
    path = tmp_path / 'p.yaml'
    path.write_text('polyline_mapper_node:\n  ros__parameters:\n    fixed_frame: odom\n'
                    '    smemsf.kappa: 2.5\n    incremental:\n      buffer_scans: 4\n'
                    "    sigma: '1e-2'\n")
    config = load_mapper_config(str(path), ['margin=0.5'])
    assert (config.smemsf.kappa, config.buffer_scans, config.smemsf.sigma, config.margin) == \
        (2.5, 4, 0.01, 0.5)
    assert load_fit_config(str(path)).kappa == 2.5       # the fit takes the smemsf.* entries


@pytest.mark.parametrize('block, name', [
    ('    smemsf:\n      sigmaa: 0.02\n', 'smemsf.sigmaa'),
    ('    incremental.bogus: 1\n', 'incremental.bogus'),
])
def test_a_typo_in_a_ros_parameter_file_is_named_not_dropped(tmp_path, block, name):
    # Node parameters (fixed_frame) are not the mapper's and are passed over; a key in the
    # smemsf / incremental groups that is no parameter was dropped without a word.
    path = tmp_path / 'p.yaml'
    path.write_text('polyline_mapper_node:\n  ros__parameters:\n    fixed_frame: odom\n' + block)
    for load in (load_mapper_config, load_fit_config):
        with pytest.raises(ConfigError, match=f'unknown parameter {name}'):
            load(str(path))


@pytest.mark.parametrize('item, words', [
    ('kappa=-1', ['--set kappa=-1', 'smemsf.kappa must be in [0, 100]']),
    ('buffer_scans=0', ['incremental.buffer_scans must be in [1, 1000]']),
    ('seed=1.5', ['seed must be an integer']),
    ('init=spiral', ['smemsf.init must be one of diagonals, single, random']),
    ('nonsense=1', ["unknown key 'nonsense'", 'kappa']),
])
def test_set_values_are_checked_against_the_table(item, words):
    with pytest.raises(ConfigError) as err:
        load_mapper_config(None, [item])
    assert all(w in str(err.value) for w in words), str(err.value)


def test_automatic_settings_take_none_and_every_core_entry_is_readable():
    assert read_values(None, ['sigma=none'])['sigma'] is None
    names = [s.name.partition('.')[2] for s in all_params()
             if s.name.startswith(('smemsf.', 'incremental.'))]
    values = read_values(None, [f'{n}={s.default}' for n, s in zip(names, [
        s for s in all_params() if s.name.startswith(('smemsf.', 'incremental.'))])])
    assert set(values) == set(names)


def test_a_parameter_file_with_several_nodes_gives_this_nodes_block(tmp_path):
    # A whole robot's file (Nav2's style): the first block was read, whichever node it was
    # for (here AMCL's: its sigma_hit never reached the mapper, nor did smemsf.kappa). Now the
    # polyline_mapper_node block, in any namespace, merged over a /** one; several robots'
    # blocks are refused by name (a new-user audit: robot1's sigma was used for robot2).
    path = tmp_path / 'robot.yaml'
    path.write_text('amcl:\n  ros__parameters:\n    sigma: 0.2\n'
                    '/**:\n  ros__parameters:\n    smemsf:\n      sigma: 0.03\n'
                    'robot1:\n  polyline_mapper_node:\n    ros__parameters:\n'
                    '      smemsf:\n        kappa: 2.5\n')
    config = load_mapper_config(str(path))
    assert (config.smemsf.sigma, config.smemsf.kappa) == (0.03, 2.5)
    path.write_text('/robot1/polyline_mapper_node:\n  ros__parameters:\n    sigma: 0.05\n'
                    'robot2:\n  polyline_mapper_node:\n    ros__parameters:\n      sigma: 0.01\n')
    with pytest.raises(ConfigError, match=r'2 blocks for this node \(/robot1/polyline_mapper_'
                                          r'node, /robot2/polyline_mapper_node\)'):
        load_mapper_config(str(path))
    path.write_text('amcl:\n  ros__parameters:\n    sigma: 0.2\n'
                    'map_server:\n  ros__parameters:\n    yaml_filename: x.yaml\n')
    with pytest.raises(ConfigError, match='2 node blocks, none named polyline_mapper_node'):
        load_mapper_config(str(path))
    # one block, whatever its name (a renamed node), is still read
    path.write_text('mapper:\n  ros__parameters:\n    smemsf.sigma: 0.04\n')
    assert load_mapper_config(str(path)).smemsf.sigma == 0.04
