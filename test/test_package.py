"""Packaging: package.xml dependencies, install layout, config file in step with the code."""

import xml.etree.ElementTree as ET

from conftest import REPO
from polyline_mapper.core import SMEMSFConfig
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


def test_config_yaml_lists_every_parameter_with_its_default():
    data = yaml.safe_load((REPO / 'config' / 'polyline_mapper.yaml').read_text())
    params = data['polyline_mapper_node']['ros__parameters']['smemsf']
    defaults = SMEMSFConfig().to_dict()
    assert set(params) == set(defaults)
    for key, value in defaults.items():
        want = 0.0 if value is None else value
        assert params[key] == want, (key, params[key], want)
