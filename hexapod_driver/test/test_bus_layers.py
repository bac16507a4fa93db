"""The driver bus's layers against the bus that holds them: each uses only what it declares of it."""
import ast
import importlib
import inspect
from typing import Generic, Protocol

import pytest

from hexapod_driver.bus import DynamixelBus
from hexapod_driver.config import DriverConfig


@pytest.mark.parametrize('module, host_name', [('servo_setup', 'SetupHost'), ('policy', 'PolicyHost'),
                                               ('loop', 'LoopHost')])
def test_each_layer_uses_only_what_it_declares_of_the_bus_and_the_bus_has_it(robot, module, host_name):
    mod = importlib.import_module(f'hexapod_driver.bus.{module}')
    host = getattr(mod, host_name)
    declared = {k for cls in host.__mro__ if cls not in (object, Protocol, Generic)
                for k in (*getattr(cls, '__annotations__', {}), *vars(cls)) if not k.startswith('_')}
    used = set()
    for node in ast.walk(ast.parse(inspect.getsource(mod))):
        if isinstance(node, ast.Attribute) and (
                (isinstance(node.value, ast.Name) and node.value.id == 'bus')
                or (isinstance(node.value, ast.Attribute) and node.value.attr == 'bus'
                    and isinstance(node.value.value, ast.Name) and node.value.value.id == 'self')):
            used.add(node.attr)
    assert used, f'{module}: no use of the bus found'
    assert used <= declared, f'{module} uses {sorted(used - declared)} of the bus without declaring it in {host_name}'
    assert isinstance(DynamixelBus(robot, DriverConfig()), host)
    assert not isinstance(object(), host)
