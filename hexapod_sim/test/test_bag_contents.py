"""The one bag loader (hexapod_sim.bagio.load_bag): the typed contents of the reference bags, the
IMU as one ImuSeries, and bad input as one line."""
import numpy as np
import pytest
from bag_samples import JS, REPO, T0, joint_state, write_bag

from hexapod_model import contract
from hexapod_model.imu import ImuReading, ImuSeries
from hexapod_model.joints import Joint
from hexapod_sim.bagio import BagContents, BagError, load_bag
from hexapod_sim.bagio.contents import TOPICS

BAGS = REPO / 'bags'

FEMUR1 = Joint(1, 'femur')


def test_a_walk_bag_holds_every_series_typed():
    bag = load_bag(BAGS / 'tripod_blocks_adaptive')
    assert isinstance(bag, BagContents) and bag.warnings == ()
    assert set(TOPICS) <= bag.topics
    assert len(bag.swing_downs) == 13 and bag.swing_downs[0].msg.detector == 'adaptive'
    assert all(a.t_s <= b.t_s for a, b in zip(bag.swing_downs, bag.swing_downs[1:]))
    js = bag.joint_states
    assert len(js) == len(js.stamp_ns) == len(js.log_ns) == len(js.name) == len(js.position) > 1000
    assert all(abs(s - n * 1e-9) < 1e-6 for s, n in zip(js.stamp_s[:50], js.stamp_ns[:50]))
    femur = js.per_joint()[FEMUR1]
    assert femur.shape[1] == 2 and np.all(np.diff(femur[:, 0]) >= 0)
    assert js.per_joint(log_time=True)[FEMUR1].shape == (len(femur), 3)
    assert len(bag.joint_commands) > 100 and bag.detections
    d = bag.detections[0]
    assert 1 <= d.leg <= 6 and isinstance(d.stopped, bool) and d.t_s >= d.swing_start_s
    assert len(bag.power) > 10 and np.all(bag.power.values >= 0)
    assert bag.truth_pose.values.shape == (len(bag.truth_pose), 3)
    assert isinstance(bag.imu, ImuSeries) and bag.imu.quat_wxyz.shape == (len(bag.imu), 4) and len(bag.imu) > 100
    assert np.median(bag.imu.accel[:, 2]) == pytest.approx(9.81, abs=0.5)    # a trunk on its legs feels about g
    assert bag.scene and 'blocks' in bag.scene


def test_only_the_topics_asked_for_are_read():
    bag = load_bag(BAGS / 'discrepancy_demo', topics=(contract.JOINT_COMMANDS, contract.JOINT_STATES))
    assert len(bag.joint_commands) and len(bag.joint_states)
    assert not bag.swing_downs and not len(bag.imu) and bag.scene is None
    with pytest.raises(ValueError, match='clock'):
        load_bag(BAGS / 'discrepancy_demo', topics=(contract.CLOCK,))


def test_the_sims_imu_samples_come_back_from_a_bag_as_one_series(tmp_path):
    """ImuReading (the plant's sample) -> /imu in a bag -> ImuSeries -> the same samples."""
    rng = np.random.default_rng(1)
    stamps = [T0 + k * 2_500_000 for k in range(6)]
    readings = [ImuReading(contract.stamp_seconds(contract.stamp_dict_ns(t_ns)), q / np.linalg.norm(q),
                           rng.normal(size=3), rng.normal(size=3))
                for t_ns, q in zip(stamps, rng.normal(size=(6, 4)))]
    msgs = []
    for t_ns, r in zip(stamps, readings):
        w, x, y, z = r.quat_wxyz.tolist()
        msgs.append((contract.bag_topic(contract.IMU), 'sensor_msgs/msg/Imu', {
            'header': {'stamp': contract.stamp_dict_ns(t_ns), 'frame_id': 'trunk'},
            'orientation': {'x': x, 'y': y, 'z': z, 'w': w},
            'angular_velocity': dict(zip('xyz', r.gyro.tolist())),
            'linear_acceleration': dict(zip('xyz', r.accel.tolist()))}, t_ns))
    series = load_bag(write_bag(tmp_path / 'imu', msgs)).imu
    expected = ImuSeries.from_readings(readings)
    for k in ('t_s', 'accel', 'gyro', 'quat_wxyz'):
        assert np.array_equal(getattr(series, k), getattr(expected, k)), k


def _one_line(exc) -> str:
    text = str(exc.value)
    assert '\n' not in text
    return text


def test_bad_input_is_one_line_naming_the_bag(tmp_path):
    with pytest.raises(BagError) as e:
        load_bag(tmp_path / 'nope')
    assert _one_line(e).startswith(str(tmp_path / 'nope')) and 'no such bag' in str(e.value)
    states = write_bag(tmp_path / 'states', [(contract.bag_topic(contract.JOINT_STATES), JS,
                                              joint_state(T0, ['leg1_femur'], [0.1]), T0)])
    with pytest.raises(BagError) as e:
        load_bag(states, required={contract.JOINT_COMMANDS: 'the goals are replayed'})
    assert _one_line(e) == f'{states}: no /joint_commands topic - the goals are replayed'
    wrong = write_bag(tmp_path / 'wrong', [(contract.bag_topic(contract.JOINT_STATES), JS,
                                            joint_state(T0, ['leg1_femur'], [0.1]), T0),
                                           ('/imu', 'std_msgs/msg/String', {'data': 'x'}, T0)])
    with pytest.raises(BagError) as e:
        load_bag(wrong)
    assert _one_line(e) == f'{wrong}: /imu is recorded as std_msgs/msg/String, expected sensor_msgs/msg/Imu'
    short = write_bag(tmp_path / 'short', [(contract.bag_topic(contract.JOINT_STATES), JS,
                                            joint_state(T0, ['leg1_femur', 'leg1_tibia'], [0.1]), T0)])
    with pytest.raises(BagError) as e:
        load_bag(short)
    assert _one_line(e).startswith(f'{short}: /joint_states message') and 'names 2 joint' in str(e.value)


def test_a_topic_whose_stored_definition_lacks_a_contract_field_is_one_line(tmp_path):
    """A damaged schema record that still parses (a bit flip made /imu's field ``header`` ``jeader``):
    the loader read the messages field by field into an AttributeError traceback."""
    from hexapod_sim.bagio import BagReader, BagWriter
    ref = BagReader(BAGS / 'tripod_blocks_adaptive')
    bag = tmp_path / 'renamed'
    topics = (contract.bag_topic(contract.JOINT_STATES), '/imu')
    with BagWriter(bag) as w:
        for topic in topics:
            text = ref.schema_text(topic)
            w.add_topic(topic, ref.topics()[topic], definition=text.replace('std_msgs/Header header', 'std_msgs/Header jeader', 1)
                        if topic == '/imu' else text)
        for topic, msg_type, t_ns, raw in ref.messages(topics, end_ns=ref.start_ns + 10**8, raw=True):
            w.write(topic, msg_type, raw, t_ns)
    with pytest.raises(BagError) as e:
        load_bag(bag)
    assert _one_line(e).startswith(f'{bag}: /imu message at t=') and "no attribute 'header'" in str(e.value)
    assert 'the definition the bag stores for sensor_msgs/msg/Imu is not the installed one' in str(e.value)


def test_the_discrepancy_tool_gives_one_line_and_exit_2_for_a_bag_without_its_topics(tmp_path, capsys):
    from hexapod_sim.discrepancy.cli import main as discrepancy
    states = write_bag(tmp_path / 'states', [(contract.bag_topic(contract.JOINT_STATES), JS,
                                              joint_state(T0, ['leg1_femur'], [0.1]), T0)])
    assert discrepancy([str(states), '--no-progress']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'no /joint_commands topic - ' in err[0], err
