"""Packaging: package.xml dependencies, install layout, config file in step with the code."""

import os
import re
import xml.etree.ElementTree as ET

from conftest import REPO
from polyline_mapper.core import SMEMSFConfig
from polyline_mapper.core.incremental import IncrementalConfig
from polyline_mapper.params import all_params, defaults, settings_from
import pytest
import yaml


def test_package_xml_format3_with_real_dependencies():
    root = ET.parse(REPO / 'package.xml').getroot()
    assert root.get('format') == '3' and root.findtext('name') == 'polyline_mapper'
    deps = {e.text for e in root if e.tag in ('depend', 'exec_depend')}
    for dep in ('rclpy', 'sensor_msgs', 'visualization_msgs', 'geometry_msgs', 'std_msgs',
                'nav_msgs', 'std_srvs', 'python3-numpy', 'python3-scipy',
                'polyline_mapper_msgs'):
        assert dep in deps, dep
    assert root.find('export/build_type').text == 'ament_python'
    # Every ROS package the code imports is declared (tf2_ros's Python module is tf2_ros_py).
    imported = set()
    for path in list((REPO / 'polyline_mapper').rglob('*.py')) + list(
            (REPO / 'launch').glob('*.py')):
        for m in re.finditer(r'^\s*(?:from|import) (\w+)', path.read_text(), re.M):
            name = m.group(1)
            if name.endswith(('_msgs', '_srvs', '_interfaces')) or name in (
                    'rclpy', 'tf2_ros', 'launch', 'launch_ros', 'ament_index_python'):
                imported.add('tf2_ros_py' if name == 'tf2_ros' else name)
    assert {'rclpy', 'sensor_msgs', 'tf2_msgs', 'launch_ros', 'ament_index_python'} <= imported
    assert imported <= deps, sorted(imported - deps)
    # ... and so is every Python library with a rosdep key; none is declared that is not used
    keys = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml',
            'matplotlib': 'python3-matplotlib', 'tqdm': 'python3-tqdm'}
    libs = {keys[m.group(1)] for path in (REPO / 'polyline_mapper').rglob('*.py')
            for m in re.finditer(r'^\s*(?:from|import) (\w+)', path.read_text(), re.M)
            if m.group(1) in keys}
    assert libs == {d for d in deps if d in keys.values()}, (libs, deps)
    assert 'tf2_ros_py' not in deps or 'tf2_ros_py' in imported
    msgs = ET.parse(REPO / 'polyline_mapper_msgs' / 'package.xml').getroot()
    assert msgs.find('export/build_type').text == 'ament_cmake'
    assert msgs.findtext('member_of_group') == 'rosidl_interface_packages'


def test_setup_installs_marker_package_xml_config_and_scripts_for_ros2_run():
    text = (REPO / 'setup.py').read_text()
    for needle in ("'resource/' + package_name", "['package.xml']", "glob('config/*.yaml')",
                   "glob('launch/*.launch.py')", 'console_scripts'):
        assert needle in text, needle
    cfg = (REPO / 'setup.cfg').read_text()
    assert 'script_dir=$base/lib/polyline_mapper' in cfg
    assert 'install_scripts=$base/lib/polyline_mapper' in cfg
    assert (REPO / 'resource' / 'polyline_mapper').is_file()


def test_every_shipped_parameter_file_applies_under_any_namespace():
    # Keyed /**: a file keyed by the node's name is silently ignored when the node runs under a
    # namespace (-r __ns:=/robot1, a launch file's PushRosNamespace) or another name.
    for path in sorted((REPO / 'config').glob('*.yaml')):
        assert list(yaml.safe_load(path.read_text())) == ['/**'], path.name


def test_config_yaml_lists_every_parameter_with_its_default():
    data = yaml.safe_load((REPO / 'config' / 'polyline_mapper.yaml').read_text())
    params = data['/**']['ros__parameters']['smemsf']
    defaults = SMEMSFConfig().to_dict()
    assert set(params) == set(defaults)
    for key, value in defaults.items():
        want = 0.0 if value is None else value
        assert params[key] == want, (key, params[key], want)


def flatten(tree: dict, prefix: str = '') -> dict:
    """Return a nested parameter mapping as {'a.b': value}, as ROS 2 reads a parameter file."""
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(flatten(value, f'{prefix}{key}.'))
        else:
            out[prefix + key] = value
    return out


def test_config_yaml_holds_every_node_parameter_with_its_default_and_type():
    data = yaml.safe_load((REPO / 'config' / 'polyline_mapper.yaml').read_text())
    params = flatten(data['/**']['ros__parameters'])
    want = defaults()
    assert set(params) == set(want), set(params) ^ set(want)
    for key, value in want.items():
        # Same value and same type: a 1 where a double is declared would fail to load.
        assert params[key] == value and type(params[key]) is type(value), (key, params[key])
    settings_from(params)                     # and the shipped values validate


def test_parameter_table_covers_the_mapper_configuration():
    names = {p.name for p in all_params()}
    for f in IncrementalConfig.__dataclass_fields__:
        assert f == 'smemsf' or f'incremental.{f}' in names, f
    for f in SMEMSFConfig.__dataclass_fields__:
        assert f'smemsf.{f}' in names, f
    for p in all_params():
        generic = p.description.startswith(('IncrementalConfig.', 'SMEMSFConfig.'))
        assert p.description and not generic, p.name
        if p.lo is not None:                  # the default lies in the declared range
            assert p.lo <= p.default <= p.hi, p.name


@pytest.mark.parametrize('name, value, match', [
    ('smemsf.kappa', 0.0, 'smemsf.kappa must be a finite number > 0'),
    ('incremental.buffer_scans', 0, 'incremental.buffer_scans'),
    ('pose_source', 'gps', 'pose_source must be one of tf, odom'),
    ('marker_color', [1.0, 0.0, 0.0], 'marker_color'),
    ('marker_color', [1.0, 0.0, 0.0, 2.0], 'marker_color'),
    ('update_every_n_scans', 51, 'at most scan_buffer_size'),
    ('transform_tolerance', float('nan'), 'transform_tolerance must be finite'),
    ('scan_buffer_size', 1.5, 'scan_buffer_size must be of type int'),
    ('fixed_frame', ' ', 'fixed_frame must not be empty'),
    ('fixed_frame', '/map', "must not start with '/'"),
])
def test_bad_parameter_values_are_refused_naming_the_parameter(name, value, match):
    values = defaults()
    values[name] = value
    with pytest.raises(ValueError, match=match):
        settings_from(values)


def test_launch_file_starts_the_installed_executable_with_the_installed_config():
    import ast
    path = REPO / 'launch' / 'polyline_mapper.launch.py'
    text = path.read_text()
    compile(text, str(path), 'exec')
    tree = ast.parse(text)
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)} | {
        n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
    assert 'generate_launch_description' in {f.name for f in tree.body
                                             if isinstance(f, ast.FunctionDef)}
    for needle in ("package='polyline_mapper'", "executable='polyline_mapper_node'",
                   "'polyline_mapper.yaml'", 'get_package_share_directory', "'config'"):
        assert needle in text, needle
    assert {'Node', 'DeclareLaunchArgument', 'LaunchConfiguration'} <= names
    setup = (REPO / 'setup.py').read_text()
    # (the node's main behind an import-time Ctrl-C handler: console.node_main)
    assert "'polyline_mapper_node = polyline_mapper.console:node_main'" in setup
    from polyline_mapper.console import node_main
    assert callable(node_main)


def launch_node(monkeypatch, **given) -> tuple:
    """
    Run the launch file's description with launch arguments ``given``: (declared, node kwargs).

    launch and launch_ros are not on PyPI: stand-ins record what the file builds (the
    arguments it declares, the keyword arguments of the Node its OpaqueFunction returns) and
    resolve a LaunchConfiguration from the arguments given, else the declared defaults.
    """
    import runpy
    import sys
    import types

    class Made:
        def __init__(self, *args, **kwargs):
            self.args, self.kwargs = args, kwargs

    class LaunchConfiguration:
        def __init__(self, name):
            self.name = name

        def perform(self, context):
            return context[self.name]

    kinds = {k: type(k, (Made,), {}) for k in ('LaunchDescription', 'DeclareLaunchArgument',
                                               'OpaqueFunction', 'Node')}
    fakes = {'launch': {'LaunchDescription': kinds['LaunchDescription']},
             'launch.actions': {k: kinds[k] for k in ('DeclareLaunchArgument', 'OpaqueFunction')},
             'launch.substitutions': {'LaunchConfiguration': LaunchConfiguration},
             'launch_ros': {}, 'launch_ros.actions': {'Node': kinds['Node']},
             'ament_index_python': {}, 'ament_index_python.packages': {
                 'get_package_share_directory': lambda package: f'/opt/ros/share/{package}'}}
    for name, attrs in fakes.items():
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, module)
    path = REPO / 'launch' / 'polyline_mapper.launch.py'
    actions = runpy.run_path(str(path))['generate_launch_description']().args[0]
    declared = {a.args[0]: a.kwargs for a in actions if type(a).__name__ ==
                'DeclareLaunchArgument'}
    assert set(given) <= set(declared), set(given) - set(declared)
    context = {k: v['default_value'] for k, v in declared.items()} | given
    opaque, = [a for a in actions if type(a).__name__ == 'OpaqueFunction']
    node, = opaque.kwargs['function'](context)
    return declared, node.kwargs


def test_launch_arguments_override_the_parameter_file_only_when_given(monkeypatch):
    config = '/opt/ros/share/polyline_mapper/config/polyline_mapper.yaml'
    declared, node = launch_node(monkeypatch)
    assert declared['params_file']['default_value'] == config
    assert (node['package'], node['executable'], node['name']) == (
        'polyline_mapper', 'polyline_mapper_node', 'polyline_mapper_node')
    # By default the file's pose_source and scan_matching rule: only use_sim_time is set.
    assert node['parameters'] == [config, {'use_sim_time': False}]
    assert node['remappings'] == [('scan', 'scan'), ('odom', 'odom')]
    assert node['namespace'] == ''
    _, node = launch_node(monkeypatch, namespace='robot1')       # one node per robot
    assert node['namespace'] == 'robot1' and node['remappings'][0] == ('scan', 'scan')
    # A robot with only odometry: one switch (issue 19), then the node's own check.
    _, node = launch_node(monkeypatch, pose_source='odom', scan_matching='True',
                          use_sim_time='true', params_file='/my.yaml', scan_topic='/base_scan')
    file, overrides = node['parameters']
    assert file == '/my.yaml' and node['remappings'][0] == ('scan', '/base_scan')
    assert overrides == {'use_sim_time': True, 'pose_source': 'odom', 'scan_matching': True}
    assert set(overrides) <= {p.name for p in all_params()} | {'use_sim_time'}
    settings_from(defaults() | {k: v for k, v in overrides.items() if k != 'use_sim_time'})
    _, node = launch_node(monkeypatch, scan_matching='false')
    assert node['parameters'][1] == {'use_sim_time': False, 'scan_matching': False}
    # odometry without matching maps in the odometry's frame (an integration audit: the
    # launch file offered pose_source odom but no way to set fixed_frame with it)
    _, node = launch_node(monkeypatch, pose_source='odom', fixed_frame='odom')
    assert node['parameters'][1] == {'use_sim_time': False, 'pose_source': 'odom',
                                     'fixed_frame': 'odom'}
    settings_from(defaults() | {'pose_source': 'odom', 'fixed_frame': 'odom'})
    assert declared['pose_source']['choices'] == ['', 'tf', 'odom', 'scan']
    with pytest.raises(ValueError, match="scan_matching must be true or false, got 'yes'"):
        launch_node(monkeypatch, scan_matching='yes')


def test_the_no_free_space_preset_turns_only_the_evidence_off_and_loads_everywhere():
    # config/no_free_space.yaml is given after polyline_mapper.yaml (node), or alone (--config):
    # node parameters of the declared types, the mapper's evidence off, every other value default.
    from polyline_mapper.config import load_fit_options, load_mapper_config
    path = REPO / 'config' / 'no_free_space.yaml'
    params = flatten(yaml.safe_load(path.read_text())['/**']['ros__parameters'])
    want = defaults()
    assert set(params) <= set(want), set(params) - set(want)
    for key, value in params.items():
        assert type(value) is type(want[key]) and value != want[key], (key, value)
    settings_from(dict(want, **params))
    off = {'free_space_window': 0, 'free_space_ghosts': 0,
           'free_space_hit_margin': 0.0, 'free_space_memory': 0.0}
    assert load_mapper_config(str(path)) == IncrementalConfig(**off)
    fit_config, extra = load_fit_options(str(path))
    assert fit_config == SMEMSFConfig() and extra == {'free_space_window': 0,
                                                      'free_space_hit_margin': 0.0}
    # Without a file the batch fit uses the beams' evidence (the window's -1 is 10 there).
    assert load_fit_options() == (SMEMSFConfig(), {'free_space_window': 10,
                                                   'free_space_hit_margin': 0.03})
    assert load_fit_options(overrides=['free_space_window=-1'])[1]['free_space_window'] == 10
    assert 'no_free_space.yaml' in (REPO / 'README.md').read_text()


def test_the_lds01_preset_is_node_parameters_of_their_declared_types():
    # config/lds01.yaml (a TurtleBot3-class lidar) loads as node parameters after
    # polyline_mapper.yaml and as --config: only the noise scale differs from the defaults.
    path = REPO / 'config' / 'lds01.yaml'
    params = flatten(yaml.safe_load(path.read_text())['/**']['ros__parameters'])
    want = defaults()
    assert params == {'smemsf.sigma': 0.025} and type(want['smemsf.sigma']) is float
    settings_from(dict(want, **params))
    assert 'config/lds01.yaml' in (REPO / 'README.md').read_text()


def test_the_free_space_preset_is_the_default_with_scan_matching_too():
    # The defaults' window is -1 (auto: 10 with the poses given, 0 with scan matching); the
    # preset sets it to 10 and every other evidence value as the defaults do.
    from polyline_mapper.config import load_mapper_config
    path = REPO / 'config' / 'free_space.yaml'
    params = flatten(yaml.safe_load(path.read_text())['/**']['ros__parameters'])
    want = defaults()
    assert want['incremental.free_space_window'] == -1
    assert params.pop('incremental.free_space_window') == 10
    assert params and all(want[key] == value and type(want[key]) is type(value)
                          for key, value in params.items()), params
    preset = load_mapper_config(str(path))
    assert preset == IncrementalConfig(free_space_window=10)
    assert preset == IncrementalConfig().resolved() == preset.resolved(scan_matching=True)
    assert IncrementalConfig().resolved(scan_matching=True).free_space_window == 0


def test_the_node_tests_find_the_node_in_a_colcon_install(tmp_path, monkeypatch):
    # `colcon test` on a ROS install runs the system Python; the node is then under a prefix on
    # AMENT_PREFIX_PATH, where `ros2 run` finds it, not beside Python.
    import rosnode
    exe = tmp_path / 'install' / 'polyline_mapper' / 'lib' / 'polyline_mapper'
    exe.mkdir(parents=True)
    (exe / 'polyline_mapper_node').write_text('#!/bin/sh\n')
    monkeypatch.setattr(rosnode.sys, 'executable', str(tmp_path / 'usr' / 'bin' / 'python3'))
    monkeypatch.setenv('AMENT_PREFIX_PATH', os.pathsep.join(
        [str(tmp_path / 'install' / 'polyline_mapper_msgs'), str(exe.parents[1])]))
    assert rosnode.node_executable() == exe / 'polyline_mapper_node'
