"""
The console scripts: ``cli.main`` and the node's ``main`` behind imports that cost nothing.

The command line imports numpy, scipy and the core before ``cli.main`` can catch anything; a
Ctrl-C in that first half second would show a traceback from inside an import. Here the
import itself is inside the handler, so an interrupt at any moment ends in one line.
"""

import sys

EXIT_INTERRUPTED = 130


def main(argv=None) -> int:
    """Run ``polyline_mapper.cli.main``; a Ctrl-C while it loads is one line, exit code 130."""
    try:
        from .cli import main as run
        return run(argv)
    except KeyboardInterrupt:
        print('polyline-mapper: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED


NODE_HELP = """\
usage: polyline_mapper_node [--ros-args [-p NAME:=VALUE ...] [--params-file FILE]
                                        [-r FROM:=TO ...]]

The polyline_mapper ROS 2 node: maps LaserScan messages (scan) into polylines, published as
polyline_mapper_msgs/PolylineMap (polyline_map), visualization_msgs/MarkerArray
(polyline_map/markers) and nav_msgs/OccupancyGrid (map). Every parameter with its default:
config/polyline_mapper.yaml in the source (share/polyline_mapper/config/ in a colcon
install); each one's description and range, while it runs:
ros2 param describe /polyline_mapper_node NAME. It takes no options of its own: ROS arguments
only, after --ros-args.
"""


def node_main(args=None) -> int:
    """
    Run ``polyline_mapper.ros.node.main`` (``polyline_mapper_node``), loading it here.

    The node installs its signal handlers once rclpy, numpy and scipy are loaded and rclpy is
    initialised; a Ctrl-C before that ends the process quietly (exit code 0), as one after it
    does. ``-h`` / ``--help`` before any ``--ros-args`` prints ``NODE_HELP`` instead (rclpy
    ignores other arguments: the node started, a review of 2026-12-02).
    """
    own = list(sys.argv if args is None else args)[1:]
    if '--ros-args' in own:
        own = own[:own.index('--ros-args')]
    if '-h' in own or '--help' in own:
        print(NODE_HELP, end='')
        return 0
    try:
        from .ros.node import main as run
        return run(args)
    except KeyboardInterrupt:
        return 0


if __name__ == '__main__':
    sys.exit(main())
