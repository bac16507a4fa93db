"""Every ServoBus implementation declares the capabilities it implements (hexapod_model.bus), implements
each one it declares, and declares each one it implements; callers ask ``isinstance``, never getattr."""
import ast
import inspect
import re
from pathlib import Path

import pytest

from hexapod_driver.bus.core import DynamixelBus
from hexapod_driver.local_bus import LocalDriverBus
from hexapod_locomotion.core.odometry_tap import OdometryTap
from hexapod_locomotion.nodes.ros_bus import RosBus
from hexapod_locomotion.trials.trial_runner import ProbeBus
from hexapod_model.bus import CAPABILITIES, ServoBus
from hexapod_sim.node.local_bus import LocalSimBus
from hexapod_sim.physics.plant import HexapodSim

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ('hexapod_model', 'hexapod_driver', 'hexapod_sim', 'hexapod_locomotion')
IMPLEMENTATIONS = (DynamixelBus, LocalDriverBus, LocalSimBus, RosBus, ProbeBus, OdometryTap, HexapodSim)
PROTOCOLS = (ServoBus, *CAPABILITIES)


def members(protocol) -> tuple[set[str], set[str]]:
    """(methods, data attributes) a protocol asks for."""
    methods = {n for n, v in vars(protocol).items() if inspect.isfunction(v) and not n.startswith('_')}
    return methods, set(vars(protocol).get('__annotations__', {}))


def implements(cls, name: str, data: bool) -> bool:
    """Defined by the class itself or a concrete base (not the protocol's empty stub)."""
    concrete = [k for k in cls.__mro__ if not getattr(k, '_is_protocol', False) and k is not object]
    if any(name in vars(k) for k in concrete):
        return True
    return data and any(re.search(rf'self\.{name}\s*[:=]', inspect.getsource(k)) for k in concrete)


@pytest.mark.parametrize('cls', IMPLEMENTATIONS, ids=lambda c: c.__name__)
def test_each_implementation_declares_exactly_what_it_implements(cls):
    assert ServoBus in cls.__mro__, f'{cls.__name__} does not declare ServoBus'
    for protocol in PROTOCOLS:
        methods, data = members(protocol)
        have = {n for n in methods if implements(cls, n, False)} | {n for n in data if implements(cls, n, True)}
        if protocol in cls.__mro__:
            assert have == methods | data, f'{cls.__name__} declares {protocol.__name__} without {(methods | data) - have}'
        else:
            assert have != methods | data, f'{cls.__name__} implements {protocol.__name__} without declaring it'


def test_the_checker_sees_a_missing_member_and_an_undeclared_capability():
    from hexapod_model.bus import Scheduled

    class Half(ServoBus, Scheduled):        # declares Scheduled, lacks set_schedule
        t_com_s = 0.001

        def now(self): ...
        def sync_write(self, goals_rad): ...
        def read_position(self, joint): ...
        def wait_until(self, t): ...

    assert not implements(Half, 'set_schedule', False) and implements(Half, 'now', False)
    assert isinstance(Half(), Scheduled)      # why the test looks at definitions, not isinstance


def _bus_classes(tree) -> list[str]:
    need = members(ServoBus)[0]
    return [n.name for n in ast.walk(tree) if isinstance(n, ast.ClassDef)
            and need <= {m.name for m in n.body if isinstance(m, ast.FunctionDef)}]


def test_every_bus_in_the_packages_is_checked_here():
    found = set()
    for pkg in PACKAGES:
        for path in (REPO / pkg / pkg).rglob('*.py'):
            found |= set(_bus_classes(ast.parse(path.read_text())))
    assert found - {'ServoBus'} == {c.__name__ for c in IMPLEMENTATIONS}


def test_callers_ask_isinstance_not_getattr():
    probe = re.compile(r'(getattr|hasattr)\((self\.)?(bus|_bus|sim)\b')
    hits = [f'{p.relative_to(REPO)}:{i}' for pkg in PACKAGES for p in (REPO / pkg / pkg).rglob('*.py')
            for i, line in enumerate(p.read_text().splitlines(), 1) if probe.search(line)]
    assert not hits, hits
