"""Configuration read through the parameter table: files, ROS 2 parameter files and --set."""

from polyline_mapper.config import ConfigError, load_fit_config, load_mapper_config, read_values
from polyline_mapper.params import all_params
import pytest


def test_the_shipped_parameter_file_gives_the_defaults(tmp_path):
    from polyline_mapper.core.incremental import IncrementalConfig
    from conftest import REPO
    config = load_mapper_config(str(REPO / 'config' / 'polyline_mapper.yaml'))
    assert config == IncrementalConfig()


def test_replay_names_the_node_parameters_of_a_file_it_does_not_read(tmp_path, capsys):
    # A TurtleBot user's parameter file with chord_knots: median (then off the default) mapped
    # with arc knots without a word (replay takes it from --chord-knots). Node parameters set
    # off their defaults are named now, with the flag; the shipped file, all defaults, names
    # none.
    from conftest import REPO
    from polyline_mapper.cli import main
    from polyline_mapper.config import unread_node_params
    for name in ('polyline_mapper.yaml', 'lds01.yaml', 'rplidar.yaml', 'free_space.yaml',
                 'no_free_space.yaml'):
        assert unread_node_params(str(REPO / 'config' / name)) == [], name
    path = tmp_path / 'tb3.yaml'
    path.write_text('/**:\n  ros__parameters:\n    chord_knots: arc\n    transform_timeout: 0.1'
                    '\n    fixed_frame: map\n    smemsf:\n      sigma: 0.025\n')
    assert unread_node_params(str(path)) == ['chord_knots: arc (replay: --chord-knots)',
                                             'transform_timeout: 0.1']
    out = tmp_path / 'map.json'
    assert main(['replay', 'sim:hall', '--config', str(path), '-o', str(out), '-q']) == 0
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'not read by replay' in err and '--chord-knots' in err
    assert load_mapper_config(str(path)).smemsf.sigma == 0.025      # the smemsf entry is read


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
