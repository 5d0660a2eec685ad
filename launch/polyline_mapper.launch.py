"""
Launch polyline_mapper_node with the installed parameter file.

    ros2 launch polyline_mapper polyline_mapper.launch.py
    ros2 launch polyline_mapper polyline_mapper.launch.py params_file:=/path/my.yaml \
        scan_topic:=/base_scan use_sim_time:=true

The parameter file is keyed by node name (polyline_mapper_node); copy the installed one
(share/polyline_mapper/config/polyline_mapper.yaml) to change the frames, the pose source or
the fit.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    config = os.path.join(get_package_share_directory('polyline_mapper'), 'config',
                          'polyline_mapper.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=config,
                              description='ROS 2 parameter file for polyline_mapper_node'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='Use /clock (bag playback, simulation)'),
        DeclareLaunchArgument('scan_topic', default_value='scan',
                              description='sensor_msgs/LaserScan input'),
        DeclareLaunchArgument('odom_topic', default_value='odom',
                              description='nav_msgs/Odometry input (pose_source odom)'),
        Node(
            package='polyline_mapper',
            executable='polyline_mapper_node',
            name='polyline_mapper_node',
            output='screen',
            emulate_tty=True,
            parameters=[LaunchConfiguration('params_file'),
                        {'use_sim_time': LaunchConfiguration('use_sim_time')}],
            remappings=[('scan', LaunchConfiguration('scan_topic')),
                        ('odom', LaunchConfiguration('odom_topic'))],
        ),
    ])
