"""Benchmark: real-time factor of the simulation (not a test; prints figures).

Scenario: the full robot on the ``blocks`` terrain, standing on the block field and stepping with
the scripted open-loop tripod gait (goals tabulated every 10 ms before timing so only the simulator
is measured; a goal is written once per 18-read cycle, 18 ms, in every variant), all 18 servos
emulated at 1 kHz.

1. raw physics + firmware (``HexapodSim.step``), no bus traffic;
2. through the bus as the controller uses it (``SimBusLoop``: sequential reads of all 18 joints,
   1 ms each, one sync write per read cycle);
3. the ROS ``sim_node`` running as fast as possible (real_time_factor 0), publishing every topic on
   loopback in its own ROS domain, without and with recording to a bag.

Target: raw simulation >= 30x real time on one core; where the time goes and what was tried is in
docs/performance.md. The machine is shared: each figure
is the best of ``--repeats`` runs (wall clock), and the CPU time of the process is shown too.
Run: ``./hexapod run hexapod_sim bench_sim``.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np
from tqdm import tqdm

from hexapod_model.description import ALL_JOINTS, load_robot

TARGET_RTF = 30.0
GOAL_PERIOD_S = 0.01


def _sim(robot):
    from hexapod_sim.physics.plant import HexapodSim
    return HexapodSim(robot, terrain='blocks', start_xy_m=(0.8, 0.0))


def _gait_table(robot, sim_s: float) -> list[dict]:
    """Goals of the scripted gait every 10 ms, computed up front: only the simulator is timed."""
    from hexapod_sim.tools.render import scripted_tripod
    gait = scripted_tripod(robot)
    return [gait(k * GOAL_PERIOD_S) for k in range(int(round(sim_s / GOAL_PERIOD_S)) + 1)]


def _run_raw(robot, goals, sim_s: float) -> tuple[float, float]:
    """One run of the raw simulation: (wall, CPU) seconds for ``sim_s`` simulated seconds."""
    sim = _sim(robot)
    cycle = len(ALL_JOINTS) * sim.t_com_s         # the same write instants as the bus run
    w0, c0 = time.perf_counter(), time.process_time()
    while sim.now() < sim_s:
        sim.sync_write(goals[int(sim.now() / GOAL_PERIOD_S)])
        sim.step(cycle)
    out = time.perf_counter() - w0, time.process_time() - c0
    if sim.warnings():
        raise RuntimeError(f'MuJoCo warnings during the benchmark: {sim.warnings()}')
    return out


def _run_bus(robot, goals, sim_s: float) -> tuple[float, float]:
    """One run through the bus (SimBusLoop, the sim node's loop without ROS)."""
    from hexapod_sim.node.bus_master_loop import SimBusLoop
    sim = _sim(robot)
    loop = SimBusLoop(sim, clock_period_s=0.0)
    w0, c0 = time.perf_counter(), time.process_time()
    while sim.now() < sim_s:
        loop.command(goals[int(sim.now() / GOAL_PERIOD_S)])
        loop.run(max_reads=loop.cycle_reads)
    return time.perf_counter() - w0, time.process_time() - c0


def bench_mujoco_alone(robot, sim_s: float, repeats: int) -> float:
    """Reference: the same trajectory by MuJoCo alone (``mujoco.rollout`` in C with the torques the
    firmware produced, recorded beforehand): what the physics costs without any emulation."""
    import mujoco
    from mujoco import rollout
    goals = _gait_table(robot, sim_s + 0.1)
    sim = _sim(robot)
    cycle = len(ALL_JOINTS) * sim.t_com_s
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.empty(mujoco.mj_stateSize(sim.model, spec))
    mujoco.mj_getState(sim.model, sim.data, state0, spec)
    ctrl = []
    while sim.now() < sim_s:                     # record the per-step torques (not timed)
        sim.sync_write(goals[int(sim.now() / GOAL_PERIOD_S)])
        t_end = sim.now() + cycle
        while sim.now() < t_end - 1e-12:
            sim.step(sim.dt)
            ctrl.append(sim.data.ctrl.copy())
    ctrl = np.array(ctrl)[None]
    m, d = sim.model, mujoco.MjData(sim.model)
    best = float('inf')
    for _ in range(repeats):
        w0 = time.perf_counter()
        rollout.rollout(m, d, state0[None], ctrl)
        best = min(best, time.perf_counter() - w0)
    return ctrl.shape[1] * sim.dt / best


def bench_raw_and_bus(robot, sim_s: float, repeats: int, progress) -> tuple[tuple, tuple]:
    """Raw and bus runs interleaved (the machine is shared: both see the same load); best of each."""
    goals = _gait_table(robot, sim_s + 0.1)
    raw, bus = [], []
    for _ in range(repeats):
        raw.append(_run_raw(robot, goals, sim_s))
        progress.update(1)
        bus.append(_run_bus(robot, goals, sim_s))
        progress.update(1)
    best = lambda runs: (sim_s / min(r[0] for r in runs), sim_s / min(r[1] for r in runs))  # noqa: E731
    return best(raw), best(bus)


def bench_ros(wall_s: float, record: bool, domain_id: int, progress) -> tuple[float, int]:
    """Run sim_node in this process at real_time_factor 0 for ``wall_s``; returns (RTF, messages)."""
    os.environ['ROS_DOMAIN_ID'] = str(domain_id)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from hexapod_sim.node.sim_node import SimNode
    tmp = tempfile.TemporaryDirectory(prefix='bench_sim_')
    params = [Parameter('terrain', value='blocks'), Parameter('start_x_m', value=0.8),
              Parameter('real_time_factor', value=0.0)]
    if record:
        params.append(Parameter('record', value=os.path.join(tmp.name, 'bag')))
    rclpy.init(args=['bench_sim'])
    node = None
    try:
        node = SimNode(parameter_overrides=params)
        rec = node.recorder
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        t_sim0 = node.sim.now()
        w0 = time.perf_counter()
        while time.perf_counter() - w0 < wall_s:
            ex.spin_once(timeout_sec=0.01)
        t_sim1 = node.sim.now()
        node.close()                  # the bag's writer thread writes what is still queued: part of the cost
        rtf = (t_sim1 - t_sim0) / (time.perf_counter() - w0)
        count = rec.count if rec is not None else 0
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
        tmp.cleanup()
    progress.update(1)
    return rtf, count


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--sim-seconds', type=float, default=5.0, help='simulated seconds per raw/bus run')
    ap.add_argument('--repeats', type=int, default=3, help='runs per figure (best is reported)')
    ap.add_argument('--ros-seconds', type=float, default=5.0, help='wall seconds per ROS run (0 = skip ROS)')
    ap.add_argument('--domain-id', type=int, default=87, help='ROS_DOMAIN_ID of the ROS part (own domain)')
    args = ap.parse_args(argv)
    robot = load_robot()
    _sim(robot).step(0.01)                         # warm-up (imports, first compile of the model)
    load0 = os.getloadavg()[0]
    n_ros = 2 if args.ros_seconds > 0 else 0
    with tqdm(total=2 * args.repeats + n_ros, desc='bench_sim', unit='run', leave=False) as progress:
        raw, bus = bench_raw_and_bus(robot, args.sim_seconds, args.repeats, progress)
        alone = bench_mujoco_alone(robot, args.sim_seconds, args.repeats)
        ros = ros_rec = None
        if n_ros:
            ros = bench_ros(args.ros_seconds, False, args.domain_id, progress)
            ros_rec = bench_ros(args.ros_seconds, True, args.domain_id, progress)
    print(f'scenario: blocks terrain, scripted tripod gait, 18 servos at 1 kHz, physics step '
          f'{_sim(robot).dt * 1e3:g} ms; best of {args.repeats} x {args.sim_seconds:g} s simulated; '
          f'load average {load0:.2f} before, {os.getloadavg()[0]:.2f} after, on {os.cpu_count()} cores')
    print(f'raw sim (physics + firmware):      {raw[0]:6.1f}x real time (wall)   {raw[1]:6.1f}x (CPU time)   '
          f'target >= {TARGET_RTF:g}x: {"MET" if raw[0] >= TARGET_RTF else "MISSED"}')
    print(f'through the bus (reads at 1 ms):   {bus[0]:6.1f}x real time (wall)   {bus[1]:6.1f}x (CPU time)')
    print(f'reference, MuJoCo alone (rollout): {alone:6.1f}x real time (wall; same trajectory, no emulation)')
    if ros is not None:
        print(f'sim_node, ROS publishing:          {ros[0]:6.1f}x real time (wall, {args.ros_seconds:g} s, '
              f'ROS_DOMAIN_ID={args.domain_id}, loopback)')
        print(f'sim_node, ROS publishing + bag:    {ros_rec[0]:6.1f}x real time (wall; {ros_rec[1]} messages recorded)')


if __name__ == '__main__':
    main()
