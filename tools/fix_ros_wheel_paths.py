#!/usr/bin/env python3
"""Rewrite the wheel builder's paths in the ROS 2 wheels' installed CMake files.

The ros-jazzy-* PyPI wheels were built in a manylinux container whose Python lives
at /opt/python/cp311-cp311. Their exported CMake targets (e.g.
share/std_msgs/cmake/export_std_msgs__rosidl_generator_pyExport.cmake) name

    /opt/python/cp311-cp311/include/python3.11
    /opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include

as INTERFACE_INCLUDE_DIRECTORIES. CMake refuses to use an imported target whose
include directory does not exist, so any interface package depending on std_msgs
etc. fails to configure on a fresh machine. This script replaces those two paths
with this interpreter's Python include directory and numpy's include directory.

Only files inside the given prefix (the project's venv) are touched. It is
idempotent: after a run no builder path is left, so a second run changes nothing.
Usage: python fix_ros_wheel_paths.py PREFIX   (run with the venv's python)
"""
import pathlib
import re
import sys
import sysconfig

import numpy

BUILDER = r'/opt/python/cp3\d+-cp3\d+'
PY_INC = re.compile(BUILDER + r'/include/python3\.\d+')
NP_INC = re.compile(BUILDER + r'/lib/python3\.\d+/site-packages/numpy/(?:_core|core)/include')
ANY = re.compile(BUILDER)


def main(prefix: str) -> int:
    root = pathlib.Path(prefix).resolve()
    py_inc = sysconfig.get_paths()['include']
    np_inc = numpy.get_include()
    for need in (pathlib.Path(py_inc) / 'Python.h', pathlib.Path(np_inc) / 'numpy'):
        if not need.exists():
            print(f'fix_ros_wheel_paths: ERROR: {need} does not exist; '
                  'the Python development headers or numpy are missing', file=sys.stderr)
            return 1
    files = [p for pat in ('share/*/cmake/*.cmake', 'lib/cmake/**/*.cmake')
             for p in root.glob(pat) if p.is_file()]
    changed = 0
    leftovers = []
    for path in files:
        text = path.read_text(encoding='utf-8', errors='surrogateescape')
        if '/opt/python/' not in text:
            continue
        new = PY_INC.sub(py_inc, text)
        new = NP_INC.sub(np_inc, new)
        if ANY.search(new):
            leftovers.append(str(path.relative_to(root)))
        if new != text:
            path.write_text(new, encoding='utf-8', errors='surrogateescape')
            changed += 1
    print(f'fix_ros_wheel_paths: {changed} of {len(files)} CMake files rewritten '
          f'(Python include -> {py_inc}, numpy include -> {np_inc})')
    if leftovers:
        print('fix_ros_wheel_paths: WARNING: other builder paths remain in: '
              + ', '.join(leftovers), file=sys.stderr)
    return 0


if __name__ == '__main__':
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    sys.exit(main(sys.argv[1]))
