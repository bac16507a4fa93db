"""Node parameters as dataclasses: one declaration carries type, default, description, range,
choices and whether the value may change at run time. No rclpy here (the ROS side is
:mod:`hexapod_model.node_params`), so library code, ``--help`` texts and tests use the same rules.

A schema is a plain dataclass whose parameter fields are made with :func:`param`::

    @dataclass(frozen=True)
    class PacerParams:
        real_time_factor: float = param(1.0, 'simulated seconds per wall second; 0 = as fast as possible',
                                        min=0.0, read_only=False)
        terrain: str = param('flat', 'terrain to walk on', choices=('flat', 'blocks'))

A field made with ``param(..., exposed=False)`` is a library setting: declared and checked the same
way, but no node parameter (nor a field of a schema merged with :func:`merged_schema`). Fields without
:func:`param` metadata are neither declared nor checked. Types come from the annotations: ``bool``,
``int``, ``float``, ``str``, ``list[str]`` or ``tuple[str, ...]`` (``X | None`` = the default is filled
in by the node, e.g. from the robot description, or None is a value of its own). Floats must be finite; ``min``/``max``
are inclusive unless ``min_exclusive`` is set (ROS ranges are inclusive, so an exclusive bound is
declared as its inclusive limit and checked here). :func:`check` returns the reason a value is
refused, :func:`validate` raises :class:`ParameterError` naming the parameter and the allowed values.
"""
from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

_KEY = 'hexapod_param'
TYPES = (bool, int, float, str, list)


class ParameterError(ValueError):
    """A parameter value is refused; the message names the parameter and what is allowed."""

    def __init__(self, name: str, reason: str):
        super().__init__(f'parameter {name}: {reason}')
        self.name = name
        self.reason = reason


@dataclass(frozen=True)
class ParamSpec:
    """How one parameter is declared and checked (filled in by :func:`specs` with name and type)."""

    description: str
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False
    choices: tuple | None = None
    read_only: bool = True
    rule: Callable[[Any], str | None] | None = None    # extra check: reason or None
    exposed: bool = True             # a node parameter (False: a library setting)
    name: str = ''
    type: type = object
    default: Any = None
    optional: bool = False           # the annotation is X | None

    def allowed(self) -> str:
        """The allowed values in words, for error messages and descriptions."""
        if self.choices is not None:
            return 'one of ' + ', '.join(str(c) for c in self.choices)
        kind = {bool: 'true or false', int: 'an integer', float: 'a finite number', str: 'a string',
                list: 'a list of strings'}[self.type]
        if self.min is not None and self.max is not None:
            lo = '(' if self.min_exclusive else '['
            return f'{kind} in {lo}{_fmt(self.min)}, {_fmt(self.max)}]'
        if self.min is not None:
            return f'{kind} {">" if self.min_exclusive else ">="} {_fmt(self.min)}'
        if self.max is not None:
            return f'{kind} <= {_fmt(self.max)}'
        return kind

    def full_description(self) -> str:
        text = f'{self.description} [{self.allowed()}]'
        if self.read_only:
            text += ' (read-only: set at start)'
        return text


def _fmt(v) -> str:
    return f'{v:g}' if isinstance(v, float) else str(v)


def param(default, description: str, *, min=None, max=None, min_exclusive: bool = False, choices=None,
          read_only: bool = True, rule: Callable[[Any], str | None] | None = None, exposed: bool = True):
    """A dataclass field that is a node parameter, or with ``exposed=False`` a library setting (see the
    module docstring)."""
    spec = ParamSpec(description, min=min, max=max, min_exclusive=min_exclusive,
                     choices=tuple(choices) if choices is not None else None, read_only=read_only, rule=rule,
                     exposed=exposed)
    if isinstance(default, tuple):
        return dataclasses.field(default=default, metadata={_KEY: spec})
    if isinstance(default, list):
        items = tuple(default)
        return dataclasses.field(default_factory=lambda: list(items), metadata={_KEY: spec})
    return dataclasses.field(default=default, metadata={_KEY: spec})


def _base_type(hint) -> type:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) != 1:
            raise TypeError(f'parameter type {hint}: only X or X | None are supported')
        return _base_type(args[0])
    if origin in (list, tuple):
        args = typing.get_args(hint)
        if args[:1] != (str,):
            raise TypeError(f'parameter type {hint}: only list[str] is supported among lists')
        return list
    if hint not in TYPES:
        raise TypeError(f'parameter type {hint}: not one of bool, int, float, str, list[str]')
    return hint


def _optional(hint) -> bool:
    return typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in typing.get_args(hint)


def specs(schema, library: bool = False) -> dict[str, ParamSpec]:
    """{name: ParamSpec} of the parameter fields of a schema class (or instance), in field order;
    ``library``: the library settings (``exposed=False``) too."""
    cls = schema if isinstance(schema, type) else type(schema)
    hints = typing.get_type_hints(cls)
    out = {}
    for f in dataclasses.fields(cls):
        spec = f.metadata.get(_KEY)
        if spec is None or not (spec.exposed or library):
            continue
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        out[f.name] = dataclasses.replace(spec, name=f.name, type=_base_type(hints[f.name]), default=default,
                                          optional=_optional(hints[f.name]))
    return out


def values(schema, source, library: bool = False) -> dict[str, Any]:
    """{name: value} of ``schema``'s parameter fields (``library``: and library settings) read from
    ``source``, any object with attributes of those names (an instance of a schema merged from it)."""
    return {name: getattr(source, name) for name in specs(schema, library)}


def merged_schema(name: str, groups: Iterable[type], module: str, doc: str = '',
                  defaults: Mapping[str, Any] | None = None) -> type:
    """A frozen dataclass whose fields are the parameter fields of ``groups``, in order, each with its
    type, default and declaration (so :func:`specs` of it is theirs): a configuration that spans several
    groups (a trial: the walk's own settings, the gait's, the controller's and the detector's) without
    restating any of them. ``defaults``: the merged class's own default of a field (a trial's terrain),
    checked against the field's declaration. ``module``: where the class is defined (pickling finds it
    by name there)."""
    defaults = dict(defaults or {})
    fields_, seen = [], {}
    for group in groups:
        hints = typing.get_type_hints(group)
        for f in dataclasses.fields(group):
            spec = f.metadata.get(_KEY)
            if spec is None or not spec.exposed:
                continue
            if f.name in seen:
                raise TypeError(f'{name}: {f.name} is declared by both {seen[f.name]} and {group.__name__}')
            seen[f.name] = group.__name__
            if f.name in defaults:
                why = check(specs(group)[f.name], defaults[f.name])
                if why is not None:
                    raise TypeError(f'{name}: default of {f.name} {why}')
                field = dataclasses.field(default=defaults.pop(f.name), metadata=f.metadata)
            else:
                field = dataclasses.field(default=f.default, default_factory=f.default_factory, metadata=f.metadata)
            fields_.append((f.name, hints[f.name], field))
    if defaults:
        raise TypeError(f'{name}: no field(s) {sorted(defaults)} to give a default')
    cls = dataclasses.make_dataclass(name, fields_, frozen=True)
    cls.__module__, cls.__qualname__ = module, name
    cls.__doc__ = doc or cls.__doc__
    return cls


def coerce(spec: ParamSpec, value):
    """The value as the parameter's type (an integer for a float parameter is taken as that float)."""
    if spec.type is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if spec.type is list and isinstance(value, (list, tuple)):
        return [v for v in value if v != '']          # [''] declares an empty string list in ROS
    return value


def check(spec: ParamSpec, value) -> str | None:
    """Why ``value`` is refused for this parameter (None: accepted)."""
    value = coerce(spec, value)
    t = spec.type
    ok_type = (isinstance(value, bool) if t is bool else
               isinstance(value, t) and not isinstance(value, bool) if t in (int, float) else
               isinstance(value, list) and all(isinstance(v, str) for v in value) if t is list else
               isinstance(value, t))
    if not ok_type:
        return f'must be {spec.allowed()}, got {value!r}'
    if t is float and not math.isfinite(value):
        return f'must be {spec.allowed()}, got {value!r}'
    if spec.rule is not None:
        why = spec.rule(value)
        if why is not None:
            return why
    if spec.choices is not None and value not in spec.choices:
        return f'must be {spec.allowed()}, got {value!r}'
    if spec.min is not None and (value <= spec.min if spec.min_exclusive else value < spec.min):
        return f'must be {spec.allowed()}, got {_fmt(value)}'
    if spec.max is not None and value > spec.max:
        return f'must be {spec.allowed()}, got {_fmt(value)}'
    return None


def validate(instance) -> None:
    """Raise :class:`ParameterError` for the first parameter field or library setting of ``instance``
    that is refused (``None`` in an ``X | None`` field = filled in later by the node, or no value: not checked)."""
    for name, spec in specs(instance, library=True).items():
        value = getattr(instance, name)
        if value is None and spec.optional:
            continue
        why = check(spec, value)
        if why is not None:
            raise ParameterError(name, why)


def build(schema: type, values: Mapping[str, Any], **library_fields):
    """An instance of ``schema`` from parameter values (checked, coerced)."""
    table = specs(schema)
    kwargs = {}
    for name, value in values.items():
        spec = table[name]
        why = check(spec, value)
        if why is not None:
            raise ParameterError(name, why)
        kwargs[name] = coerce(spec, value)
    return schema(**kwargs, **library_fields)


def help_lines(schemas: Iterable[type], defaults: Mapping[str, Any] | None = None) -> list[str]:
    """'  name (default ...): description [allowed]' per parameter, for ``--help`` texts."""
    defaults = defaults or {}
    lines = []
    for schema in schemas:
        for name, spec in specs(schema).items():
            lines.append(f'  {name} (default {defaults.get(name, spec.default)!r}): {spec.full_description()}')
    return lines


@dataclass(frozen=True)
class RobotSource:
    """The robot description a node loads: every node and tool takes the same two parameters, so one
    description (robot.yaml + overlays) feeds model, sim, controller and driver alike."""

    robot_description: str = param('', 'robot description YAML; empty = the packaged hexapod_model/data/robot.yaml')
    robot_overlays: list[str] = param([], 'overlay YAMLs merged over the description, in order (servo '
                                      "mounting, identified effects, ...); [''] = none")

    def load(self):
        """The :class:`hexapod_model.description.Robot` (raises DescriptionError naming the file and key)."""
        from hexapod_model.description import load_robot
        return load_robot(self.robot_description or None, list(self.robot_overlays))


@dataclass(frozen=True)
class ReadTime:
    """How long one position read takes on the bus: the bus masters' and the controller's parameter."""

    t_com_s: float = param(0.0, 'duration of one position read [s]: 0.001 hardware-accelerated, 0.016 stock USB '
                           "adapter (in the simulation a multiple of the physics step); 0 = the robot description's "
                           'bus.t_com_s', min=0.0)


@dataclass(frozen=True)
class NodeSpec:
    """Which schemas make up a node's parameters: for its ``config/<executable>.yaml``, launch files
    and the tests that check them. ``robot_defaults``: defaults the robot description sets."""

    package: str
    executable: str
    node_name: str
    schemas: tuple
    robot_defaults: Callable[[Any], dict] | None = None

    def names(self) -> list[str]:
        return [n for s in self.schemas for n in specs(s)]

    def defaults(self) -> dict:
        return self.robot_defaults(RobotSource().load()) if self.robot_defaults else {}


def _yaml_value(v) -> str:
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, str):
        return "'" + v.replace("'", "''") + "'"
    if isinstance(v, list):
        return '[' + ', '.join(_yaml_value(x) for x in (v or [''])) + ']'     # ROS cannot type an empty list
    return repr(v)


def params_yaml(node: NodeSpec) -> str:
    """The node's parameter file (``--ros-args --params-file``): every declared parameter at its default,
    each with its description and allowed values as a comment."""
    defaults = node.defaults()
    lines = [f'# Parameters of {node.package} {node.executable} (node name {node.node_name}), all at their defaults.',
             '# Generated from the schema dataclasses by tools/params_files.py; edit a copy,',
             f'# start with: ros2 run {node.package} {node.executable} --ros-args --params-file <this file>',
             f'{node.node_name}:', '  ros__parameters:']
    for schema in node.schemas:
        for name, spec in specs(schema).items():
            lines.append(f'    # {spec.full_description()}')
            lines.append(f'    {name}: {_yaml_value(defaults.get(name, spec.default))}')
    return '\n'.join(lines) + '\n'


@dataclass(frozen=True)
class RobotStateParams:
    tf_rate_hz: float = param(50.0, 'rate of /tf from the latest /joint_states [Hz]', min=0.0, min_exclusive=True)


MODEL_NODE = NodeSpec('hexapod_model', 'model_node', 'model_node', (RobotSource,))
ROBOT_STATE_NODE = NodeSpec('hexapod_model', 'robot_state', 'robot_state', (RobotSource, RobotStateParams))
