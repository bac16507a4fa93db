"""LocalSimBus hands a controller in its process what the sim node publishes: every read (its own
scheduled reads included) and every IMU sample, the same values, in the controller's thread."""
import threading

from hexapod_model.description import load_robot
from hexapod_model.imu import ImuReading
from hexapod_sim.node.bus_master_loop import JointSample, SimBusLoop
from hexapod_sim.node.local_bus import LocalSimBus, Pacer
from hexapod_sim.physics.plant import HexapodSim


def test_reads_and_imu_samples_are_observed_as_they_are_emitted():
    sim = HexapodSim(load_robot(), imu_rate_hz=400.0)
    emitted = []
    bus = LocalSimBus(SimBusLoop(sim), emitted.extend, Pacer(0.0, sim.now), threading.RLock())
    reads, imu, threads = [], [], set()

    def on_read(names, positions, stamp):
        reads.extend((n, p, stamp) for n, p in zip(names, positions))
        threads.add(threading.get_ident())

    bus.observe_reads(on_read)
    bus.observe_imu(imu.append)
    bus.set_schedule(['leg2_coxa', 'leg2_tibia'])
    bus.read_position('leg1_femur')
    bus.wait_until(0.1)
    bus.read_position('leg3_femur')
    assert reads == [(e.joint, e.theta_rad, e.t_s) for e in emitted if isinstance(e, JointSample)]
    assert {j for j, _, _ in reads} == {'leg1_femur', 'leg2_coxa', 'leg2_tibia', 'leg3_femur'}
    assert imu == [e for e in emitted if isinstance(e, ImuReading)] and len(imu) >= 30      # 400 Hz for 0.1 s
    assert threads == {threading.get_ident()}
