"""Fixtures shared by this package's tests: the robot description, an emulated bus, and a probe node.

``ros`` runs on the calling test file's own ``DOMAIN_ID`` (DDS on loopback); the probe is named
after the file (``test_driver_node.py`` -> ``driver_node_test``).
"""
import pytest

import hexapod_testing as testing
from hexapod_driver.emulator import BusEmulator
from hexapod_model.description import load_robot


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture
def emu(robot, tmp_path):
    """18 emulated AX-12As behind a stable link (a test may take the port away and bring it back)."""
    with BusEmulator(robot, link_path=tmp_path / 'ttyDXL') as e:
        yield e


@pytest.fixture(scope='module')
def ros(request):
    name = request.module.__name__.rpartition('.')[2].removeprefix('test_') + '_test'
    with testing.ros_probe(name, request.module.DOMAIN_ID) as probe:
        yield probe
