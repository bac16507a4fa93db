"""robot: the hexapod's nodes composed in one process, the controller owning the bus (real time).

``ros2 run hexapod_locomotion robot`` starts, in one process and one executor,

* the bus master: ``sim_node`` (``hardware:=sim``, the MuJoCo hexapod) or ``driver_node``
  (``hardware:=driver``, the AX-12A bus on ``device``: the robot, or the bus emulator),
* ``model_node`` (the ``/predict_swing_down`` service),
* ``locomotion_node``, whose controller calls the bus master's bus directly: Algorithm 1 reads the
  femurs, decides and writes at t_con = L x T_com, as on the paper's robot, where over DDS between
  processes it cannot (docs/architecture.md).

Every node keeps its name, parameters and topics, so the graph looks as if they ran apart:
``/joint_states`` per read, ``/joint_commands`` per write, diagnostics, ``/ground_detection``,
``/cmd_vel`` in. Parameters given with ``-p`` go to every node that declares them
(``robot_description``/``robot_overlays`` are shared on purpose); a ``--params-file`` can address
each node by name.
"""
from __future__ import annotations

import sys

import rclpy
from rclpy.executors import SingleThreadedExecutor

from hexapod_locomotion.core.detector import DetectorError
from hexapod_locomotion.core.gait import GaitError
from hexapod_locomotion.core.locomotion_params import LocomotionError
from hexapod_locomotion.nodes.params import ComposedParams
from hexapod_model.bus import BusError
from hexapod_model.description import DescriptionError
from hexapod_model.node_params import NodeParams, init_node_process, node_command_line, stopping_cleanly


def _declared(context, node_name: str, *schemas):
    """The instances of ``schemas`` as a short-lived node of ``node_name`` declares their parameters (a
    bad value raises its ParameterError before any node of the robot starts)."""
    from rclpy.node import Node
    probe = Node(node_name, context=context)
    try:
        params = NodeParams(probe)
        return [params.declare(schema) for schema in schemas]
    finally:
        probe.destroy_node()


def _hardware(context) -> str:
    """The ``hardware`` parameter, read before the bus master is chosen."""
    return _declared(context, 'robot', ComposedParams)[0].hardware


def _check_parameter_names(context, hardware: str) -> None:
    """Refuse a parameter no composed node declares (a typo would run on the default), and one of the
    other bus master's (``record`` with ``hardware:=driver``: it would do nothing), before any node
    starts. ``-p`` reaches every node; a parameter file's entries addressed to one node must be its own."""
    from hexapod_driver.config import NODE as DRIVER
    from hexapod_locomotion.nodes.params import NODE as LOCOMOTION
    from hexapod_model.node_params import parameters_given, unknown_parameter
    from hexapod_model.param_schema import MODEL_NODE, specs
    from hexapod_sim.node.params import NODE as SIM
    master, other = (DRIVER, SIM) if hardware == 'driver' else (SIM, DRIVER)
    members = (master, MODEL_NODE, LOCOMOTION)
    known = set(specs(ComposedParams)).union(*(m.names() for m in members))
    elsewhere = {n: f'a {other.executable} parameter, no effect with hardware:={hardware}'
                 for n in other.names() if n not in known}
    given = parameters_given('robot', context)
    exc = unknown_parameter(given, known, elsewhere)
    if exc is not None:
        raise exc
    for m in members:
        exc = unknown_parameter(parameters_given(m.node_name, context) - given, m.names(),
                                what=f'{m.node_name} has no such parameter')
        if exc is not None:
            raise exc


def _check_locomotion_parameters(context) -> None:
    """Refuse a bad locomotion_node parameter before any node starts (the bus master's and the model
    node's start-up lines would come first)."""
    from hexapod_locomotion.nodes.params import NODE
    _declared(context, 'locomotion_node', *NODE.schemas)


def _bus_master(hardware: str):
    """(node, its bus for the controller, cleanup)."""
    if hardware == 'driver':
        from hexapod_driver.driver_node import DriverNode
        node = DriverNode()
        return node, node.local_bus(), node.shutdown_bus
    from hexapod_sim.node.sim_node import SimNode
    node = SimNode()
    return node, node.local_bus(), node.close


def help_text() -> str:
    from hexapod_locomotion.nodes.params import NODE
    from hexapod_model.cli_common import prog_name
    from hexapod_model.param_schema import help_lines
    lines = [f'usage: {prog_name("robot")} [-h] [--ros-args -p NAME:=VALUE ...]', '', __doc__.strip(), '',
             'Parameters (-p NAME:=VALUE), besides those of sim_node / driver_node and model_node:',
             *help_lines((ComposedParams, *NODE.schemas))]
    return '\n'.join(lines)


def main(args=None) -> None:
    rc = node_command_line(None if args is None else list(args)[1:], 'robot', help_text)
    if rc is not None:
        raise SystemExit(rc)
    from hexapod_locomotion.nodes.locomotion_node import LocomotionNode, spin_while_walking
    from hexapod_model.model_node import ModelNode
    from hexapod_sim.bagio import BagError
    from hexapod_sim.physics.plant import SimError
    init_node_process(args)
    nodes, cleanups, loco = [], [], None
    try:
        with stopping_cleanly('robot', (DescriptionError, GaitError, DetectorError, LocomotionError, SimError, BagError)):
            hardware = _hardware(rclpy.get_default_context())
            _check_parameter_names(rclpy.get_default_context(), hardware)
            _check_locomotion_parameters(rclpy.get_default_context())
            master, bus, cleanup = _bus_master(hardware)
            nodes.append(master)
            cleanups.append(cleanup)
            nodes.append(ModelNode())
            loco = LocomotionNode(bus=bus)
            nodes.append(loco)
            # One executor thread. No callback here waits for another callback, a service or a future
            # of this executor: the controller runs in its own thread and only publishes; the sim
            # node's recording subscriptions only enqueue (hexapod_sim.bagio.recorder_process.RecorderProcess); its
            # emergency stop, like the driver's, waits at most for the bus transaction under way.
            # rclpy's MultiThreadedExecutor (Jazzy) busy-loops while a callback waits in its thread
            # pool (ros2/rclpy#1452), holding the interpreter against the controller's thread: with
            # record:=... (~660 /ground_detection callbacks per second of walking) the robot ran at
            # 0.25-0.3 of real time, whether or not those callbacks waited for the sim's lock.
            ex = SingleThreadedExecutor()
            for n in nodes:
                ex.add_node(n)
            try:
                spin_while_walking(ex, loco)
            finally:        # sim_node's stop_on_record_error shut the context down
                if getattr(master, 'stopped_on_record_error', False):
                    raise SystemExit(1)
    except (BusError, ValueError) as exc:          # the driver's start-up: nothing left enabled
        print(f'robot: start-up failed: {exc}', file=sys.stderr)
        raise SystemExit(1)
    finally:
        if loco is not None:            # the controller first: it stops using the bus
            loco.destroy_node()
        for c in cleanups:
            c()
        for n in nodes:
            if n is not loco:
                n.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
