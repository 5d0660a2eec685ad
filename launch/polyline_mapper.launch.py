"""
Launch polyline_mapper_node with the installed parameter file.

    ros2 launch polyline_mapper polyline_mapper.launch.py
    ros2 launch polyline_mapper polyline_mapper.launch.py params_file:=/path/my.yaml \
        scan_topic:=/base_scan use_sim_time:=true
    ros2 launch polyline_mapper polyline_mapper.launch.py pose_source:=odom scan_matching:=true
    ros2 launch polyline_mapper polyline_mapper.launch.py pose_source:=odom fixed_frame:=odom
    ros2 launch polyline_mapper polyline_mapper.launch.py namespace:=robot1 \
        params_file:=/path/robot1.yaml

The parameter file is keyed /** (it applies under any namespace); copy the installed one
(share/polyline_mapper/config/polyline_mapper.yaml) to change the frames, the mount or the fit.
``use_sim_time`` is the launch argument's (default false), over any value in the file.
``pose_source`` and ``scan_matching`` left empty (the default) keep the parameter file's values;
given, they override it: ``scan_matching:=true`` for a robot with only odometry (the node then
broadcasts map -> odom), ``pose_source:=scan`` for scans alone. ``fixed_frame`` likewise: the
frame the map is built in; ``pose_source:=odom`` without scan matching maps in the odometry's
frame, so it needs ``fixed_frame:=odom`` (the file's ``map`` skips every scan, warned).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _flag(context, name: str):
    """Return launch argument ``name`` as a bool (true / false, any case), None when empty."""
    value = LaunchConfiguration(name).perform(context).strip()
    if not value:
        return None
    if value.lower() not in ('true', 'false'):
        raise ValueError(f'launch argument {name} must be true or false, got {value!r}')
    return value.lower() == 'true'


def _node(context, *args, **kwargs):
    """Return the node, its parameters resolved: the file, then the arguments given."""
    overrides = {'use_sim_time': bool(_flag(context, 'use_sim_time'))}
    pose_source = LaunchConfiguration('pose_source').perform(context)
    if pose_source:
        overrides['pose_source'] = pose_source
    scan_matching = _flag(context, 'scan_matching')
    if scan_matching is not None:
        overrides['scan_matching'] = scan_matching
    fixed_frame = LaunchConfiguration('fixed_frame').perform(context).strip()
    if fixed_frame:
        overrides['fixed_frame'] = fixed_frame
    return [Node(
        package='polyline_mapper',
        executable='polyline_mapper_node',
        name='polyline_mapper_node',
        namespace=LaunchConfiguration('namespace').perform(context),
        output='screen',
        emulate_tty=True,
        parameters=[LaunchConfiguration('params_file').perform(context), overrides],
        remappings=[('scan', LaunchConfiguration('scan_topic').perform(context)),
                    ('odom', LaunchConfiguration('odom_topic').perform(context))],
    )]


def generate_launch_description():
    config = os.path.join(get_package_share_directory('polyline_mapper'), 'config',
                          'polyline_mapper.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=config,
                              description='ROS 2 parameter file for polyline_mapper_node'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='Namespace of the node and its topics (one per '
                                          'robot); frames are parameters (fixed_frame, '
                                          'odom_frame)'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='Use /clock (bag playback, simulation)'),
        DeclareLaunchArgument('scan_topic', default_value='scan',
                              description='sensor_msgs/LaserScan input'),
        DeclareLaunchArgument('odom_topic', default_value='odom',
                              description='nav_msgs/Odometry input (pose_source odom)'),
        DeclareLaunchArgument('pose_source', default_value='',
                              choices=['', 'tf', 'odom', 'scan'],
                              description="Where poses come from; empty: the parameter file's"),
        DeclareLaunchArgument('scan_matching', default_value='',
                              description='Match scans to the map and broadcast map -> odom; '
                                          "empty: the parameter file's"),
        DeclareLaunchArgument('fixed_frame', default_value='',
                              description='The frame the map is built in (odom for '
                                          'pose_source odom without scan matching); empty: '
                                          "the parameter file's"),
        OpaqueFunction(function=_node),
    ])
