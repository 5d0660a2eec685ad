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


def node_main(args=None) -> int:
    """
    Run ``polyline_mapper.ros.node.main`` (``polyline_mapper_node``), loading it here.

    The node installs its signal handlers once rclpy, numpy and scipy are loaded and rclpy is
    initialised; a Ctrl-C before that ends the process quietly (exit code 0), as one after it
    does.
    """
    try:
        from .ros.node import main as run
        return run(args)
    except KeyboardInterrupt:
        return 0


if __name__ == '__main__':
    sys.exit(main())
