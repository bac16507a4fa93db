"""The parameter helper: a dataclass becomes declared, described, range-checked parameters; bad start
values are one ParameterError naming the parameter and the allowed values; at run time bad values
and read-only parameters are refused with a reason, and accepted changes reach the node."""
import math
import os
from dataclasses import dataclass

import pytest

from hexapod_model.param_schema import ParameterError, RobotSource, check, help_lines, param, specs, validate

rclpy = pytest.importorskip('rclpy')
from rcl_interfaces.msg import ParameterType  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from hexapod_model.node_params import NodeParams  # noqa: E402


@dataclass(frozen=True)
class Demo:
    mode: str = param('fast', 'how to run', choices=('fast', 'exact'))
    rate_hz: float = param(10.0, 'publish rate [Hz]', min=0.0, min_exclusive=True, read_only=False)
    depth: int = param(5, 'queue depth', min=1, max=100)
    verbose: bool = param(False, 'log more')
    files: list[str] = param([], 'extra files')
    gain: float | None = param(None, 'gain; default from the robot', min=0.0)
    library_only: int = 7


def test_schema_types_and_defaults():
    table = specs(Demo)
    assert list(table) == ['mode', 'rate_hz', 'depth', 'verbose', 'files', 'gain']     # library_only is no parameter
    assert [table[n].type for n in table] == [str, float, int, bool, list, float]
    assert table['rate_hz'].read_only is False and table['mode'].read_only is True
    assert Demo().files == [] and Demo().library_only == 7


@pytest.mark.parametrize('name, value, words', [
    ('mode', 'slow', 'must be one of fast, exact'),
    ('rate_hz', 0.0, 'a finite number > 0'),
    ('rate_hz', math.nan, 'a finite number > 0'),
    ('rate_hz', math.inf, 'a finite number > 0'),
    ('depth', 0, 'an integer in [1, 100]'),
    ('depth', 101, 'an integer in [1, 100]'),
    ('depth', 2.5, 'an integer in [1, 100]'),
    ('verbose', 1, 'true or false'),
    ('files', 'a.yaml', 'a list of strings'),
])
def test_check_names_the_allowed_values(name, value, words):
    why = check(specs(Demo)[name], value)
    assert why is not None and words in why, why


def test_check_accepts_good_values_and_validate_raises_one_line():
    t = specs(Demo)
    assert check(t['rate_hz'], 0.5) is None and check(t['rate_hz'], 2) is None     # an integer is a float here
    assert check(t['files'], ['']) is None                                          # ROS's empty list
    validate(Demo())
    with pytest.raises(ParameterError) as exc:
        validate(Demo(depth=0))
    assert str(exc.value) == 'parameter depth: must be an integer in [1, 100], got 0'
    assert '\n' not in str(exc.value)


def test_help_lines_show_default_range_and_read_only():
    lines = help_lines([Demo], {'gain': 2.0})
    assert "  mode (default 'fast'): how to run [one of fast, exact] (read-only: set at start)" in lines
    assert any(line.startswith('  gain (default 2.0)') for line in lines)
    assert not any('library_only' in line for line in lines)


@pytest.fixture
def ctx():
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    c = rclpy.Context()
    rclpy.init(context=c)
    yield c
    rclpy.try_shutdown(context=c)


def make(ctx, overrides=(), **defaults):
    from rclpy.node import Node
    node = Node('params_test', context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in overrides])
    params = NodeParams(node)
    return node, params, params.declare(Demo, defaults={'gain': 1.5, **defaults})


def test_declare_sets_descriptors_and_values(ctx):
    node, params, cfg = make(ctx, [('mode', 'exact'), ('files', ['a.yaml', 'b.yaml'])])
    try:
        assert cfg == Demo(mode='exact', files=['a.yaml', 'b.yaml'], gain=1.5)
        d = node.describe_parameter('depth')
        assert d.read_only and d.type == ParameterType.PARAMETER_INTEGER
        assert (d.integer_range[0].from_value, d.integer_range[0].to_value) == (1, 100)
        d = node.describe_parameter('rate_hz')
        assert not d.read_only and d.floating_point_range[0].from_value == 0.0
        d = node.describe_parameter('mode')
        assert 'one of fast, exact' in d.description and d.additional_constraints == 'one of: fast, exact'
        assert node.get_parameter('files').value == ['a.yaml', 'b.yaml']
        assert node.describe_parameter('files').type == ParameterType.PARAMETER_STRING_ARRAY
        assert node.get_parameter('gain').value == 1.5           # the node's default replaced None
    finally:
        node.destroy_node()


def test_an_integer_start_value_of_a_float_parameter_is_that_float(ctx):
    node, _, cfg = make(ctx, [('rate_hz', 3)])
    try:
        assert cfg.rate_hz == 3.0 and node.get_parameter('rate_hz').value == 3.0
    finally:
        node.destroy_node()


def test_empty_string_list_reads_back_empty(ctx):
    node, _, cfg = make(ctx)
    try:
        assert cfg.files == [] and node.get_parameter('files').value == ['']
    finally:
        node.destroy_node()


@pytest.mark.parametrize('overrides, line', [
    ([('mode', 'slow')], "parameter mode: must be one of fast, exact, got 'slow'"),
    ([('depth', 0)], 'parameter depth: must be an integer in [1, 100], got 0'),
    ([('rate_hz', 0.0)], 'parameter rate_hz: must be a finite number > 0, got 0'),
    ([('rate_hz', math.nan)], 'parameter rate_hz: must be a finite number > 0, got nan'),
    ([('depth', 'many')], "parameter depth: must be an integer in [1, 100], got 'many'"),
    ([('rate_hz', True)], 'parameter rate_hz: must be a finite number > 0, got True'),
])
def test_bad_start_value_is_one_line_naming_parameter_and_allowed_values(ctx, overrides, line):
    with pytest.raises(ParameterError) as exc:
        make(ctx, overrides)
    assert str(exc.value) == line


def test_run_time_changes_are_checked_and_applied(ctx):
    node, params, _ = make(ctx)
    seen = []
    params.on_change('rate_hz', seen.append)
    try:
        r = node.set_parameters([Parameter('rate_hz', value=-1.0)])[0]      # the descriptor's range (rclpy)
        assert not r.successful and 'rate_hz' in r.reason and 'out of range' in r.reason
        r = node.set_parameters([Parameter('rate_hz', value=0.0)])[0]       # the exclusive bound (the helper)
        assert not r.successful and r.reason == 'parameter rate_hz: must be a finite number > 0, got 0'
        r = node.set_parameters([Parameter('rate_hz', value=math.nan)])[0]
        assert not r.successful and 'rate_hz' in r.reason
        assert seen == [] and node.get_parameter('rate_hz').value == 10.0
        r = node.set_parameters([Parameter('rate_hz', value=25.0)])[0]
        assert r.successful and seen == [25.0] and params.value('rate_hz') == 25.0
    finally:
        node.destroy_node()


def test_read_only_parameters_are_refused_with_a_reason(ctx):
    node, params, _ = make(ctx)
    try:
        r = node.set_parameters([Parameter('mode', value='exact')])[0]
        assert not r.successful and 'read-only' in r.reason and 'mode' in r.reason
        assert node.get_parameter('mode').value == 'fast'
        with pytest.raises(ValueError, match='read-only'):
            params.on_change('mode', print)
    finally:
        node.destroy_node()


def test_robot_source_loads_description_and_overlays(ctx, tmp_path):
    from rclpy.node import Node
    overlay = tmp_path / 'mount.yaml'
    overlay.write_text('bus:\n  joints:\n    leg1_femur: {direction: -1, offset_ticks: 12}\n')
    node = Node('robot_source_test', context=ctx,
                parameter_overrides=[Parameter('robot_overlays', value=[str(overlay)])])
    try:
        robot = NodeParams(node).declare(RobotSource).load()
        femur = {j.joint: j for j in robot.bus.joints}['leg1_femur']
        assert (femur.direction, femur.offset_ticks) == (-1, 12)
    finally:
        node.destroy_node()


def test_ctrl_c_in_a_node_process_stops_rclpy_without_a_keyboard_interrupt(tmp_path):
    """After init_node_process, SIGINT shuts the rclpy context down and raises nothing in the main
    thread, wherever it is (a KeyboardInterrupt landing in a collected rclpy Task printed a
    traceback at Ctrl-C)."""
    import os
    import subprocess
    import sys
    script = tmp_path / 'node.py'
    script.write_text(
        'import os, signal, rclpy\n'
        'from hexapod_model.node_params import init_node_process\n'
        'init_node_process([])\n'
        'os.kill(os.getpid(), signal.SIGINT)\n'
        'try:\n'
        '    for _ in range(2_000_000):\n'          # pure Python: where Python would raise it
        '        pass\n'
        '    print("ok" if not rclpy.ok() else "context still up")\n'
        'except KeyboardInterrupt:\n'
        '    print("KeyboardInterrupt")\n'
        'rclpy.try_shutdown()\n')
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(120 + os.getpid() % 40))
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == 'ok', (r.stdout, r.stderr)
    assert 'Traceback' not in r.stderr
