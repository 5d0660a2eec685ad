"""
The ``polyline-mapper`` console script: ``cli.main`` behind imports that cost nothing.

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


if __name__ == '__main__':
    sys.exit(main())
