"""
Rewrite the wheel builder's paths in the ROS message wheels' exported CMake files.

The ros-jazzy-*-msgs wheels ship <venv>/share/*/cmake/*Export.cmake files that name the
interpreter include directory and numpy include directory of the machine that built the wheels
(/opt/python/cp311-cp311/...). CMake's generate step fails on those paths, so before building
an interface package against the venv we point them at this interpreter's directories.
Idempotent: a file that already names the right paths is left alone.
"""

import pathlib
import re
import sys
import sysconfig

import numpy


def main(venv: str) -> int:
    share = pathlib.Path(venv) / 'share'
    py_include = sysconfig.get_paths()['include']
    np_include = numpy.get_include()
    py_pat = re.compile(r'/opt/python/cp\d+-cp\d+/include/python3\.\d+')
    np_pat = re.compile(r'/opt/python/cp\d+-cp\d+/lib/python3\.\d+/site-packages/numpy/'
                        r'(?:_core|core)/include')
    changed = 0
    for path in share.glob('*/cmake/*Export.cmake'):
        text = path.read_text()
        new = np_pat.sub(np_include, py_pat.sub(py_include, text))
        if new != text:
            path.write_text(new)
            changed += 1
    print(f'fix_ament_exports: rewrote {changed} file(s) under {share}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1]))
