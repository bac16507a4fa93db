"""Every import is declared, points down the layering and is pinned.

An AST scan of every module and test of every package (imports inside functions included):
- an import of another workspace package follows the layering
  hexapod_msgs <- hexapod_model <- hexapod_driver <- hexapod_sim <- hexapod_locomotion
  (a package imports only packages to its left; hexapod_sim imports hexapod_driver only in its
  emulator plug-in, which the driver finds through an entry-point group);
- every import of another package (workspace, ROS or PyPI) is declared in the importing
  package's package.xml: <depend>/<exec_depend> for modules, also <test_depend> for tests;
  PyPI-only packages use the ``python3-<name>-pip`` rosdep key;
- every third-party import is pinned in requirements/py.txt or requirements/ros.txt.
docs/setup.md lists the declared dependencies per package.
"""
import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ['hexapod_msgs', 'hexapod_model', 'hexapod_driver', 'hexapod_sim', 'hexapod_locomotion']
# (importer, imported) pairs the layering allows only in these files (paths relative to ROOT).
# the sim uses the driver only to offer its physics to the bus emulator, and to run the stand
# calibration routine (which lives with the sim-vs-real tool) on the real bus
NARROW = {('hexapod_sim', 'hexapod_driver'): {'hexapod_sim/hexapod_sim/node/emulator_backend.py',
                                              'hexapod_sim/test/test_emulator_backend.py',
                                              'hexapod_sim/hexapod_sim/calibration/stand.py',
                                              'hexapod_sim/test/test_robot_recording.py'}}

# Python module -> (rosdep key, pip distribution pinned in requirements/). ROS packages need no
# entry: their module name is their rosdep key and their wheel is ros-<name> in requirements/ros.txt.
PYTHON_KEYS = {
    'numpy': ('python3-numpy', 'numpy'),
    'scipy': ('python3-scipy', 'scipy'),
    'yaml': ('python3-yaml', 'pyyaml'),
    'serial': ('python3-serial', 'pyserial'),
    'matplotlib': ('python3-matplotlib', 'matplotlib'),
    'PIL': ('python3-pil', 'pillow'),
    'tqdm': ('python3-tqdm', 'tqdm'),
    'numba': ('python3-numba', 'numba'),
    'llvmlite': ('python3-llvmlite', 'llvmlite'),
    'pytest': ('python3-pytest', 'pytest'),
    'sklearn': ('python3-sklearn', 'scikit-learn'),
    'threadpoolctl': ('python3-threadpoolctl', 'threadpoolctl'),
    # PyPI only (no Debian/Ubuntu package): the rosdep pip-key convention
    'mujoco': ('python3-mujoco-pip', 'mujoco'),
    'mcap': ('python3-mcap-pip', 'mcap'),
    'mcap_ros2': ('python3-mcap-ros2-support-pip', 'mcap-ros2-support'),
    'rosbags': ('python3-rosbags-pip', 'rosbags'),
    'dynamixel_sdk': ('python3-dynamixel-sdk-pip', 'dynamixel-sdk'),
    'foxglove': ('python3-foxglove-sdk-pip', 'foxglove-sdk'),
    'ray': ('python3-ray-pip', 'ray'),
    'pinocchio': ('pinocchio', 'pin'),          # a rosdep key of its own (ros-jazzy-pinocchio); here the PyPI wheel
}

# ROS packages with no PyPI wheel: declared in package.xml, imported only where installed (guarded)
UNPINNED_ROS = {'tf2_msgs'}


def _pinned() -> set[str]:
    names = set()
    for f in ('py.txt', 'ros.txt'):
        for line in (ROOT / 'requirements' / f).read_text().splitlines():
            m = re.match(r'\s*([A-Za-z0-9_.\-]+)(\[[^\]]*\])?\s*==', line)
            if m:
                names.add(re.sub(r'[-_.]+', '-', m.group(1)).lower())
    return names


def _dist(name: str) -> str:
    return re.sub(r'[-_.]+', '-', name).lower()


def _is_ros_package(module: str, pinned: set[str]) -> bool:
    d = _dist(module)
    return f'ros-{d}' in pinned or f'ros-jazzy-{d}' in pinned


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, top-level module) of every absolute import in the file."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name.split('.')[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module.split('.')[0]))
    return out


def declared(package_xml: Path) -> tuple[set[str], set[str]]:
    """(run-time keys, test-time keys) declared in a package.xml."""
    root = ET.parse(package_xml).getroot()
    run = {e.text.strip() for tag in ('depend', 'exec_depend') for e in root.iter(tag)}
    return run, run | {e.text.strip() for e in root.iter('test_depend')}


def python_packages() -> list[str]:
    return [p for p in LAYERS if (ROOT / p / p).is_dir()]


def scan(package: str):
    """Yield (file, line, module, is_test) for every third-party or workspace import of a package."""
    base = ROOT / package
    for path in sorted(base.rglob('*.py')):
        rel = path.relative_to(base)
        if rel.parts[0] not in (package, 'test'):
            continue                                   # setup.py, build leftovers
        is_test = rel.parts[0] == 'test'
        # test helpers: the test folder's own (fakes.py) and the workspace's (tests/, pytest.ini's pythonpath)
        local = {p.stem for p in (*path.parent.glob('*.py'), *(ROOT / 'tests').glob('*.py'))} if is_test else set()
        for line, mod in imports_of(path):
            if mod in sys.stdlib_module_names or mod in ('__future__', package) or mod in local:
                continue
            yield path, line, mod, is_test


def problems(package: str, pinned: set[str]) -> list[str]:
    run, test = declared(ROOT / package / 'package.xml')
    out = []
    for path, line, mod, is_test in scan(package):
        where = f'{path.relative_to(ROOT)}:{line}'
        if mod in LAYERS:
            key = mod
            if LAYERS.index(mod) >= LAYERS.index(package):
                out.append(f'{where}: {package} imports {mod}, against the layering {" <- ".join(LAYERS)}')
            elif (package, mod) in NARROW and str(path.relative_to(ROOT)) not in NARROW[(package, mod)]:
                out.append(f'{where}: {package} may import {mod} only in {sorted(NARROW[(package, mod)])}')
        elif mod in PYTHON_KEYS:
            key, dist = PYTHON_KEYS[mod]
            if _dist(dist) not in pinned:
                out.append(f'{where}: {mod} (pip {dist}) is not pinned in requirements/py.txt or ros.txt')
        elif _is_ros_package(mod, pinned) or mod in UNPINNED_ROS:
            key = mod
        else:
            out.append(f'{where}: {mod} is neither a ROS package pinned in requirements/ros.txt nor in '
                       f'PYTHON_KEYS of {Path(__file__).name} (add its rosdep key and pip name there, pin it)')
            continue
        if key not in (test if is_test else run):
            tag = 'test_depend' if is_test else 'exec_depend'
            out.append(f'{where}: imports {mod}, but {package}/package.xml does not declare <{tag}>{key}</{tag}>')
    return out


@pytest.mark.parametrize('package', python_packages())
def test_imports_are_declared_layered_and_pinned(package):
    found = problems(package, _pinned())
    assert not found, '\n'.join(found)


def test_workspace_level_tests_import_only_pinned_packages():
    pinned = _pinned()
    bad = []
    helpers = {p.stem for p in (ROOT / 'tests').glob('*.py')}
    for path in sorted((ROOT / 'tests').glob('*.py')):
        for line, mod in imports_of(path):
            if mod in sys.stdlib_module_names or mod == '__future__' or mod in LAYERS or mod in helpers:
                continue
            if not (_is_ros_package(mod, pinned) or mod in UNPINNED_ROS or (mod in PYTHON_KEYS and _dist(PYTHON_KEYS[mod][1]) in pinned)):
                bad.append(f'{path.relative_to(ROOT)}:{line}: {mod} is not pinned')
    assert not bad, '\n'.join(bad)


def test_the_check_catches_an_undeclared_import_and_an_upward_one(tmp_path, monkeypatch):
    """The scan itself: a package whose module imports an undeclared PyPI package and a package above it."""
    pkg = tmp_path / 'hexapod_model'
    (pkg / 'hexapod_model').mkdir(parents=True)
    (pkg / 'package.xml').write_text('<package format="3"><name>hexapod_model</name>'
                                     '<exec_depend>python3-numpy</exec_depend></package>')
    (pkg / 'hexapod_model' / 'm.py').write_text('import numpy\nimport scipy.optimize\n'
                                                'def f():\n    from hexapod_sim import plant\n')
    monkeypatch.setattr(sys.modules[__name__], 'ROOT', tmp_path)
    found = problems('hexapod_model', {'numpy', 'scipy'})
    assert len(found) == 3, found
    assert 'does not declare <exec_depend>python3-scipy</exec_depend>' in found[0]
    assert 'against the layering' in found[1]
    assert 'does not declare <exec_depend>hexapod_sim</exec_depend>' in found[2]


def test_setup_doc_lists_every_declared_dependency():
    """docs/setup.md has one line per package listing its package.xml dependencies."""
    text = (ROOT / 'docs' / 'setup.md').read_text()
    for package in LAYERS:
        root = ET.parse(ROOT / package / 'package.xml').getroot()
        keys = {e.text.strip() for tag in ('buildtool_depend', 'build_depend', 'depend', 'exec_depend', 'test_depend')
                for e in root.iter(tag)}
        line = next((ln for ln in text.splitlines() if ln.startswith(f'| `{package}` |')), None)
        assert line is not None, f'docs/setup.md has no dependency row for {package}'
        listed = set(re.findall(r'`([^`]+)`', line)) - {package}
        assert listed == keys, f'{package}: docs/setup.md lists {sorted(listed)}, package.xml declares {sorted(keys)}'
