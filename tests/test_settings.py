"""One source per setting: every group of settings is declared once (name, type, default, range,
description: :func:`hexapod_model.param_schema.param`), and everything derived from a declaration
agrees with it: the node parameters as ROS declares them (descriptor, range, default), the parameter
YAML files, TrialConfig's fields and the sweep's values, the detector settings a recording carries,
and the one range check the controller, the detector, the driver and the trials share."""
import math
import subprocess
from dataclasses import fields, replace
from pathlib import Path

import pytest
import yaml

from hexapod_driver.config import NODE as DRIVER
from hexapod_driver.config import DriverConfig, DriverNodeParams
from hexapod_locomotion.core.course import CourseChoice
from hexapod_locomotion.core.detector import (
    RECORDED_SETTINGS,
    DetectorConfig,
    DetectorError,
    SwingDownPhase,
    phase_from_fields,
    swing_start_fields,
)
from hexapod_locomotion.core.gait import GaitChoice
from hexapod_locomotion.core.locomotion_params import LocomotionError, LocomotionParams
from hexapod_locomotion.nodes.params import NODE as LOCOMOTION
from hexapod_locomotion.nodes.params import TERRAIN_NODE, ComposedParams, LocomotionNodeParams
from hexapod_locomotion.trials import sweep
from hexapod_locomotion.trials.trial_config import TRIAL_DEFAULTS, TRIAL_GROUPS, TrialConfig, TrialSettings
from hexapod_model.param_schema import (
    MODEL_NODE,
    ROBOT_STATE_NODE,
    ParameterError,
    ReadTime,
    RobotSource,
    RobotStateParams,
    check,
    params_yaml,
    specs,
    validate,
)
from hexapod_sim.node.params import NODE as SIM
from hexapod_sim.node.params import SimParams
from hexapod_sim.physics.scene_params import SceneParams

REPO = Path(__file__).resolve().parent.parent
NODES = (DRIVER, SIM, MODEL_NODE, ROBOT_STATE_NODE, LOCOMOTION, TERRAIN_NODE)
GROUPS = (RobotSource, ReadTime, RobotStateParams, GaitChoice, LocomotionParams, DetectorConfig, CourseChoice,
          LocomotionNodeParams, ComposedParams, SceneParams, SimParams, DriverConfig, DriverNodeParams, TrialSettings)
# The names two groups declare with a meaning of their own each (nothing else may be declared twice)
SAME_NAME_OTHER_MEANING = {
    'lockstep': {'SimParams', 'LocomotionNodeParams'},   # advance per command / drive such a bus master
    'record': {'SimParams', 'TrialSettings'},             # '' off, 'auto' or a name / a bag directory or None
}
# Parameter files that are no node's generated file, and the node whose parameters they set
OTHER_PARAMETER_FILES = {'hexapod_locomotion/config/calibration_walk.yaml': LOCOMOTION}
# groups whose constructor runs the range check, and the error it raises
CHECKED = {LocomotionParams: LocomotionError, DetectorConfig: DetectorError}


def _outside(spec):
    """Values the declaration refuses: beyond each bound, an unknown choice."""
    if spec.choices is not None:
        yield 'no such choice' if spec.type is str else -1
    if spec.min is not None:
        yield spec.min if spec.min_exclusive else spec.type(spec.min - 1)
    if spec.max is not None:
        yield spec.type(spec.max + 1)
    if spec.type is float:
        yield math.nan


def _inside(spec):
    """Values the declaration accepts: its bounds (an exclusive one nudged in), each choice, the default."""
    out = list(spec.choices or ())
    if spec.min is not None:
        out.append(spec.min + (1e-6 if spec.type is float else 1) if spec.min_exclusive else spec.min)
    if spec.max is not None:
        out.append(spec.max)
    if spec.default is not None:
        out.append(spec.default)
    return out


def test_no_setting_is_declared_twice():
    where = {}
    for group in GROUPS:
        for name in specs(group, library=True):
            where.setdefault(name, set()).add(group.__name__)
    twice = {name: groups for name, groups in where.items() if len(groups) > 1}
    assert twice == SAME_NAME_OTHER_MEANING
    for node in NODES:
        assert len(node.names()) == len(set(node.names())), node.executable


def test_every_declared_default_is_in_its_range():
    for group in GROUPS:
        for name, spec in specs(group, library=True).items():
            if spec.default is not None:
                assert check(spec, spec.default) is None, f'{group.__name__}.{name}'
        validate(group())


@pytest.mark.parametrize('group', GROUPS, ids=lambda g: g.__name__)
def test_one_range_check_refuses_what_the_declaration_refuses(group):
    """check() (node start values, run-time changes, sweeps), validate() and the constructors of the
    controller's and the detector's settings refuse exactly the values outside the declared range."""
    for name, spec in specs(group, library=True).items():
        for bad in _outside(spec):
            assert check(spec, bad) is not None, (name, bad)
            with pytest.raises(ParameterError, match=f'parameter {name}: '):
                validate(_unchecked(group, name, bad))
            if group in CHECKED:
                with pytest.raises(CHECKED[group], match=f'parameter {name}: must be'):
                    group(**{name: bad})
        for good in _inside(spec):
            assert check(spec, good) is None, (name, good)
            if group in CHECKED:
                group(**{name: good})


def _unchecked(group, name, value):
    """An instance of ``group`` with one field set, past its constructor's own check."""
    obj = object.__new__(group)
    for f in fields(group):
        object.__setattr__(obj, f.name, getattr(group(), f.name))
    object.__setattr__(obj, name, value)
    return obj


def test_trial_fields_are_the_declarations():
    """TrialConfig's fields are the groups' parameter fields, each with its declaration (and the trial's
    own defaults where TRIAL_DEFAULTS says so); the controller's, the detector's, the gait's, the course
    correction's and the read time's are locomotion_node's parameters, the scene's sim_node's."""
    trial = specs(TrialConfig)
    expected = {}
    for group in TRIAL_GROUPS:
        expected.update(specs(group))
    assert list(trial) == list(expected)
    for name, spec in trial.items():
        want = expected[name]
        if name in TRIAL_DEFAULTS:
            assert spec.default == TRIAL_DEFAULTS[name] != want.default
            want = replace(want, default=spec.default)
        assert spec == want, name
    node = {n: s for g in LOCOMOTION.schemas for n, s in specs(g).items()}
    for group in (GaitChoice, LocomotionParams, DetectorConfig, CourseChoice, ReadTime):
        for name in specs(group):
            assert node[name] == expected[name], name
    sim = {n: s for g in SIM.schemas for n, s in specs(g).items()}
    for name in specs(SceneParams):
        assert sim[name] == expected[name], name
    # what a trial builds from its config is the groups' own defaults, but where TRIAL_DEFAULTS says otherwise
    from hexapod_locomotion.trials.trial_config import detector_config, locomotion_params
    own = {n: v for n, v in TRIAL_DEFAULTS.items() if n in specs(LocomotionParams)}
    assert own and locomotion_params(TrialConfig()) == replace(LocomotionParams(), **own)
    assert detector_config(TrialConfig()) == DetectorConfig()


def _as_text(value) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, tuple):
        return ','.join(value) or 'none'
    return 'none' if value is None else str(value)


def test_the_sweep_takes_every_trial_field_as_its_declared_type():
    sweepable = sweep.sweepable()
    assert set(sweepable) == {f.name for f in fields(TrialConfig)} - set(sweep.NOT_SWEPT)
    for name, spec in sweepable.items():
        value = sweep.parse_value(name, _as_text(spec.default))
        assert value == spec.default and type(value) is type(spec.default), name
        for good in _inside(spec):
            assert sweep.parse_value(name, _as_text(good)) == good, (name, good)


def _parameter_files():
    out = {}
    for node in NODES:
        out[f'{node.package}/config/{node.executable}.yaml'] = node
    out.update(OTHER_PARAMETER_FILES)
    return out


def test_every_parameter_file_agrees_with_the_declarations():
    """Each node's config/<executable>.yaml is generated from its declarations; every parameter file
    names only parameters its node declares, with values the declarations accept."""
    tracked = subprocess.run(['git', 'ls-files', '*/config/*.yaml'], cwd=REPO, capture_output=True, text=True,
                             check=True).stdout.split()
    files = _parameter_files()
    assert set(tracked) == set(files), 'a parameter file this test does not know: add it to OTHER_PARAMETER_FILES'
    for path, node in files.items():
        text = (REPO / path).read_text()
        if path not in OTHER_PARAMETER_FILES:
            assert text == params_yaml(node), f'{path} is stale: ./hexapod shell python tools/params_files.py'
        table = {n: s for g in node.schemas for n, s in specs(g).items()}
        for target, entry in yaml.safe_load(text).items():
            assert target in (node.node_name, '/**'), (path, target)
            for name, value in entry['ros__parameters'].items():
                assert name in table, f'{path}: {name} is no parameter of {node.node_name}'
                assert check(table[name], value) is None, f'{path}: {name}: {check(table[name], value)}'


def test_a_recording_carries_the_detector_settings_and_gives_them_back():
    """SwingDownStart holds every recorded detector setting under its declared name and type, and a
    phase rebuilt from a recording has the detector it was recorded with."""
    msg = pytest.importorskip('hexapod_msgs.msg')
    types = msg.SwingDownStart.get_fields_and_field_types()
    ros_type = {float: {'double'}, int: {'uint32', 'int32', 'int64', 'uint64'}, str: {'string'}}
    table = specs(DetectorConfig, library=True)
    assert set(RECORDED_SETTINGS) == set(table) - {'stop_mode'}
    for name in RECORDED_SETTINGS:
        assert types.get(name) in ros_type[table[name].type], name
    from hexapod_model.description import load_robot
    robot = load_robot()
    config = DetectorConfig(detector='fixed', epsilon_tick=2.0, dwell_epsilon_tick=1.0, fixed_threshold_tick=15.0,
                            min_descent_m=0.005, confirm_reads=4)
    phase = SwingDownPhase(robot, [1], [0.0], [[0.5, -1.0]], [[0.8, -1.2]], 0.5, 0.001, config)
    recorded = swing_start_fields(phase)
    assert set(recorded) == set(types) - {'header'}
    assert phase_from_fields(robot, recorded, 0.0).config == config
    assert phase_from_fields(robot, recorded, 0.0, kind='adaptive').config.detector == 'adaptive'


def test_the_node_declares_each_setting_as_declared(tmp_path):
    """Each node's parameters as ROS has them: the declared names, defaults, descriptions (with the
    allowed values), read-only flags and ranges (as ros2_controllers' generate_parameter_library
    makes them)."""
    rclpy = pytest.importorskip('rclpy')
    from rclpy.node import Node

    from hexapod_model.node_params import ROS_OWN_PARAMETERS, NodeParams
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        for spec_node in NODES:
            node = Node(spec_node.node_name, context=ctx, start_parameter_services=False, enable_rosout=False)
            try:
                params = NodeParams(node)
                defaults = spec_node.defaults()
                for schema in spec_node.schemas:
                    params.declare(schema, {k: v for k, v in defaults.items() if k in specs(schema)})
                declared = set(node.list_parameters([], 0).names) - set(ROS_OWN_PARAMETERS)
                assert declared == set(spec_node.names()), spec_node.executable
                for schema in spec_node.schemas:
                    for name, spec in specs(schema).items():
                        _agrees(node, name, spec, defaults.get(name, spec.default))
            finally:
                node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def _agrees(node, name, spec, default):
    d = node.describe_parameter(name)
    value = node.get_parameter(name).value
    assert (value if spec.type is not list else [v for v in value if v]) == default, name
    assert d.description == spec.full_description() and d.read_only == spec.read_only, name
    if spec.type is float and (spec.min is not None or spec.max is not None):
        (r,) = d.floating_point_range
        assert r.from_value == (spec.min if spec.min is not None else -math.inf), name
        assert r.to_value == (spec.max if spec.max is not None else math.inf), name
    elif spec.type is int and (spec.min is not None or spec.max is not None):
        (r,) = d.integer_range
        assert r.from_value == (spec.min + spec.min_exclusive if spec.min is not None else -(2**63 - 1)), name
        assert r.to_value == (spec.max if spec.max is not None else 2**63 - 1), name
    else:
        assert not d.floating_point_range and not d.integer_range, name
    if spec.choices is not None:
        assert all(str(c) in d.additional_constraints for c in spec.choices), name
