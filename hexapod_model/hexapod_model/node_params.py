"""Declare a node's parameters from :mod:`hexapod_model.param_schema` dataclasses (the ROS side).

    params = NodeParams(node)
    src = params.declare(RobotSource)                                  # robot_description, robot_overlays
    cfg = params.declare(SimParams, defaults={'t_com_s': robot.bus.t_com_s})
    params.on_change('real_time_factor', pacer.reanchor)

Each field becomes a parameter with a :class:`ParameterDescriptor`: the description (with the
allowed values), ``FloatingPointRange``/``IntegerRange`` from min/max, ``read_only``. A start value
given with ``-p`` or ``--params-file`` that is refused raises :class:`ParameterError` (one line: the
parameter and its allowed values); the nodes' ``main`` prints it and exits 1. At run time one
on-set-parameters callback refuses bad values with the same reason; a read-only parameter is
refused by rclpy ("Trying to set a read-only parameter"), never accepted and ignored.
"""
from __future__ import annotations

import contextlib
import sys
from typing import Any, Callable, Mapping

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from hexapod_model.param_schema import ParameterError, ParamSpec, build, check, coerce, specs

INT64_MAX = 2**63 - 1
EXIT_BAD_PARAMETER = 1


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    d = ParameterDescriptor(description=spec.full_description(), read_only=spec.read_only)
    if spec.choices is not None:
        d.additional_constraints = 'one of: ' + ', '.join(str(c) for c in spec.choices)
    if spec.type is float and (spec.min is not None or spec.max is not None):
        d.floating_point_range = [FloatingPointRange(
            from_value=float(spec.min) if spec.min is not None else -float('inf'),
            to_value=float(spec.max) if spec.max is not None else float('inf'), step=0.0)]
    elif spec.type is int and (spec.min is not None or spec.max is not None):
        lo = int(spec.min) + (1 if spec.min_exclusive else 0) if spec.min is not None else -INT64_MAX
        d.integer_range = [IntegerRange(from_value=lo, to_value=int(spec.max) if spec.max is not None else INT64_MAX,
                                        step=0)]
    return d


def ros_default(spec: ParamSpec, value):
    """The value as declared to ROS: an empty string list is [''] (ROS cannot type an empty list)."""
    if spec.type is list:
        return list(value) or ['']
    return value


class NodeParams:
    """The declared parameters of one node, from one or more schema dataclasses."""

    def __init__(self, node: Node):
        self.node = node
        self.specs: dict[str, ParamSpec] = {}
        self._apply: dict[str, Callable[[Any], None]] = {}
        node.add_on_set_parameters_callback(self._on_set)
        node.add_post_set_parameters_callback(self._after_set)

    def declare(self, schema: type, defaults: Mapping[str, Any] | None = None, **library_fields):
        """Declare every parameter field of ``schema`` and return the instance built from their
        values (``defaults`` replace the schema's defaults, e.g. values of the robot description;
        ``library_fields`` fill fields that are not parameters)."""
        defaults = dict(defaults or {})
        table = specs(schema)
        unknown = set(defaults) - set(table)
        if unknown:
            raise KeyError(f'{schema.__name__} has no parameter(s) {sorted(unknown)}')
        values = {}
        for name, spec in table.items():
            default = defaults.get(name, spec.default)
            if default is None:
                raise TypeError(f'{schema.__name__}.{name}: the node must give a default (the schema has None)')
            spec = self.specs[name] = _with_default(spec, default)
            self._float_from_int(spec)
            try:
                self.node.declare_parameter(name, ros_default(spec, default), descriptor(spec))
            except InvalidParameterTypeException:
                raise ParameterError(name, f'must be {spec.allowed()}, got {self._override(name)!r}') from None
            except InvalidParameterValueException as exc:
                value = self._override(name)
                why = check(spec, value) if value is not None else None
                raise ParameterError(name, why or str(exc)) from None
            values[name] = self.node.get_parameter(name).value
        return build(schema, values, **library_fields)

    def on_change(self, name: str, apply: Callable[[Any], None]) -> None:
        """Call ``apply(value)`` after a run-time change of a writable parameter was accepted."""
        if self.specs[name].read_only:
            raise ValueError(f'parameter {name} is read-only; nothing can change it at run time')
        self._apply[name] = apply

    def value(self, name: str):
        return coerce(self.specs[name], self.node.get_parameter(name).value)

    def _float_from_int(self, spec: ParamSpec) -> None:
        """``-p t_des_s:=1`` means 1.0: rclpy would refuse an INTEGER for a DOUBLE parameter."""
        overrides = getattr(self.node, '_parameter_overrides', None)
        p = overrides.get(spec.name) if overrides is not None else None
        if spec.type is float and p is not None and type(p.value) is int:
            overrides[spec.name] = Parameter(spec.name, value=float(p.value))

    def _override(self, name: str):
        p = getattr(self.node, '_parameter_overrides', {}).get(name)
        return None if p is None else p.value

    def _on_set(self, params) -> SetParametersResult:
        for p in params:
            spec = self.specs.get(p.name)
            if spec is None:
                continue                   # use_sim_time and other parameters rclpy declares itself
            why = check(spec, p.value)
            if why is not None:
                return SetParametersResult(successful=False, reason=f'parameter {p.name}: {why}')
        return SetParametersResult(successful=True)

    def _after_set(self, params) -> None:
        for p in params:
            fn = self._apply.get(p.name)
            if fn is not None:
                fn(coerce(self.specs[p.name], p.value))


def _with_default(spec: ParamSpec, default) -> ParamSpec:
    from dataclasses import replace
    return replace(spec, default=default)


def node_command_line(argv: list[str] | None, exe: str, help_text: Callable[[], str]) -> int | None:
    """The part of a node's command line before ``--ros-args``: ``-h``/``--help`` prints
    ``help_text()`` (nothing is started, no device opened) and exit code 0 is returned; any other
    argument there (which rclpy would silently ignore, e.g. ``--gait bogus`` for ``-p gait:=bogus``)
    is refused in one line and 2 is returned; ``None``: start the node. ``argv`` without the
    program name (default ``sys.argv[1:]``)."""
    from hexapod_model.cli_common import prog_name
    argv = sys.argv[1:] if argv is None else list(argv)
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in own or '--help' in own:
        print(help_text())
        return 0
    if own:
        prog = prog_name(exe)
        print(f'{prog}: error: unrecognized arguments: {" ".join(own)} (parameters are given as '
              f'--ros-args -p NAME:=VALUE; see {prog} --help)', file=sys.stderr, flush=True)
        return 2
    return None


ROS_OWN_PARAMETERS = ('use_sim_time', 'start_type_description_service')   # rclpy declares these on every node


def parameters_given(node_name: str, context=None) -> set[str]:
    """The names of the parameters the command line and parameter files give a node called
    ``node_name`` (``-p`` for every node, a file's entries addressed to it or to ``/**``), read from a
    short-lived node of that name before the real one starts."""
    from rclpy.node import Node
    probe = Node(node_name, context=context, start_parameter_services=False, enable_rosout=False)
    try:
        return set(getattr(probe, '_parameter_overrides', None) or {})
    finally:
        probe.destroy_node()


def unknown_parameter(given, known, elsewhere: Mapping[str, str] | None = None,
                      what: str = 'no such parameter') -> ParameterError | None:
    """The refusal of the first name in ``given`` that is not in ``known`` (None: all known): it names
    the nearest known name, or the node that would take it (``elsewhere``: name -> why it has no effect
    here). QoS overrides (``qos_overrides.*``) are ROS's own."""
    import difflib
    known = set(known) | set(ROS_OWN_PARAMETERS)
    for name in sorted(given):
        if name in known or name.startswith('qos_overrides.'):
            continue
        if elsewhere and name in elsewhere:
            return ParameterError(name, elsewhere[name])
        close = difflib.get_close_matches(name, sorted(known), n=1)
        return ParameterError(name, what + (f' (did you mean {close[0]}?)' if close else
                                                           ' (--help lists them)'))
    return None


def refuse_unknown_parameters(node_name: str, known, context=None) -> None:
    """Raise :class:`ParameterError` for a parameter given to ``node_name`` that it does not declare
    (rclpy would ignore it: a typo such as ``terain:=mockup`` would run on the default)."""
    exc = unknown_parameter(parameters_given(node_name, context), known)
    if exc is not None:
        raise exc


def report(node_name: str, exc: ParameterError) -> int:
    """Print the one line for a refused start value; the exit code to use."""
    print(f'{node_name}: {exc}', file=sys.stderr, flush=True)
    return EXIT_BAD_PARAMETER


def init_node_process(args: list[str] | None = None) -> None:
    """``rclpy.init`` for a node executable, with Ctrl-C that stops it the way SIGTERM does.

    rclpy's signal handler shuts the context down (the spin loop ends with
    ``ExternalShutdownException``, then ``main`` cleans up) and then calls the Python handler that
    was installed before it. Python's default raises ``KeyboardInterrupt`` wherever the main thread
    happens to be - also inside a garbage-collected rclpy ``Task.__del__``, which Python reports as
    an ignored exception with a traceback. A handler that does nothing leaves the stop to rclpy."""
    import os
    import signal

    import rclpy
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.utilities import remove_ros_args

    from hexapod_model.cli_common import prog_name
    try:                          # parsed once first: rcl's init would also log its own [ERROR] line
        remove_ros_args(args if args is not None else sys.argv)
    except RCLError as exc:       # e.g. '-p' without NAME:=VALUE
        exe = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else 'node'
        print(f'{prog_name(exe)}: error: bad --ros-args: {rcl_reason(exc)}', file=sys.stderr, flush=True)
        raise SystemExit(2) from None
    signal.signal(signal.SIGINT, _leave_the_stop_to_rclpy)
    rclpy.init(args=args)


def rcl_reason(exc: Exception) -> str:
    """rcl's reason for refusing the ROS arguments, on one line without its source locations."""
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    for prefix in ('failed to initialize rcl: ', 'Failed to parse ROS arguments: '):
        text = text.replace(prefix, '')
    return text.split(', at ')[0]


def _leave_the_stop_to_rclpy(signum, frame) -> None:
    """SIGINT after rclpy has shut the context down: nothing more to do."""


def spin_until_shutdown(node, period_s: float = 0.1) -> None:
    """Spin ``node`` until its context is shut down (Ctrl-C, SIGTERM), re-checking every ``period_s``.

    With :func:`init_node_process` nothing interrupts the main thread at Ctrl-C; the stop comes
    from rclpy shutting the context down. ``rclpy.spin`` waits without a timeout, so a wake-up that
    races the shutdown would leave it waiting for ever; a bounded wait cannot miss it."""
    from rclpy.executors import SingleThreadedExecutor
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        while node.context.ok():
            executor.spin_once(timeout_sec=period_s)
    finally:
        executor.shutdown()


def node_help(exe: str, doc: str, schemas, defaults: Mapping[str, Any] | None = None) -> Callable[[], str]:
    """``help_text`` for :func:`run_node`: usage, the module's description, every parameter."""
    def text() -> str:
        from hexapod_model.cli_common import prog_name
        from hexapod_model.param_schema import help_lines
        return '\n'.join([f'usage: {prog_name(exe)} [-h] [--ros-args -p NAME:=VALUE ...]', '', doc.strip(), '',
                          'Parameters (-p NAME:=VALUE):', *help_lines(schemas, defaults)])
    return text


@contextlib.contextmanager
def stopping_cleanly(exe: str, errors: tuple = (), error_exit: int = 2):
    """Around a node process's start and spin: Ctrl-C and SIGTERM end it quietly (also when they
    close the context while a node is being created or is publishing); a refused parameter exits
    with :data:`EXIT_BAD_PARAMETER` and one of ``errors`` (the process's own start-up errors: a bad
    description, terrain, bag path) with ``error_exit``, each in one line."""
    import rclpy
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.exceptions import NotInitializedException
    from rclpy.executors import ExternalShutdownException
    try:
        yield
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (RCLError, NotInitializedException):
        if rclpy.ok():          # a real middleware error, not Ctrl-C/SIGTERM closing the context mid-publish
            raise               # or while a node was still being created
    except ParameterError as exc:
        raise SystemExit(report(exe, exc))
    except errors as exc:
        print(f'{exe}: {exc}', file=sys.stderr, flush=True)
        raise SystemExit(error_exit)


def run_node(exe: str, make_node: Callable[[], Any], help_text: Callable[[], str], args: list[str] | None = None,
             errors: tuple = (), error_exit: int = 2, close: Callable[[Any], None] | None = None,
             spin: Callable[[Any], None] = spin_until_shutdown, spec=None) -> None:
    """``main`` of a node executable that serves until Ctrl-C or SIGTERM.

    ``--help`` prints ``help_text()`` and starts nothing; arguments rclpy would ignore or cannot
    parse are refused in one line (:func:`node_command_line`, :func:`init_node_process`); stops and
    errors as :func:`stopping_cleanly`. At the end ``close(node)`` (the node's own cleanup), the
    node is destroyed and rclpy shut down. ``spin(node)`` serves it (default
    :func:`spin_until_shutdown`). ``spec`` (the node's :class:`~hexapod_model.param_schema.NodeSpec`):
    a parameter it does not declare is refused before the node starts."""
    import rclpy
    rc = node_command_line(None if args is None else list(args)[1:], exe, help_text)
    if rc is not None:
        raise SystemExit(rc)
    init_node_process(args)
    node = None
    try:
        with stopping_cleanly(exe, errors, error_exit):
            if spec is not None:
                refuse_unknown_parameters(spec.node_name, spec.names())
            node = make_node()
            spin(node)
    finally:
        if node is not None:
            if close is not None:
                close(node)
            node.destroy_node()
        rclpy.try_shutdown()
