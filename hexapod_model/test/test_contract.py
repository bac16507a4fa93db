"""Header stamps of the recording contract."""
import pytest

from hexapod_model import contract
from hexapod_model.contract import stamp_parts


def test_stamp_parts_carries_into_seconds():
    assert stamp_parts(12.000345) == (12, 345000)
    assert stamp_parts(1.9999999999) == (2, 0)          # rounds up into the next second, not (1, 0)
    assert stamp_parts(0.0) == (0, 0)


def test_topic_names_are_relative_so_the_stack_runs_under_a_namespace():
    names = [v for k, v in vars(contract).items() if k.isupper() and isinstance(v, str)]
    assert len(names) >= 16
    # use_sim_time listens on /clock; tf and diagnostics keep the global names the ROS tools listen on
    assert sorted(n for n in names if n.startswith('/')) == sorted(
        [contract.CLOCK, contract.TF, contract.TF_STATIC, contract.DIAGNOSTICS])
    assert contract.topic_key('/joint_states') == contract.topic_key('joint_states') == contract.JOINT_STATES
    assert contract.bag_topic(contract.SIM_TRUTH_POSE) == '/sim/body_pose'
    assert contract.bag_topic(contract.CLOCK) == '/clock'
def test_stamp_conversions_are_one_pair_in_every_form():
    from builtin_interfaces.msg import Time

    from hexapod_model.contract import stamp_dict, stamp_dict_ns, stamp_msg, stamp_ns, stamp_parts_ns, stamp_seconds
    for t in (0.0, 0.001, 12.000345, 1.9999999999, 1234.5678901):
        sec, nanosec = stamp_parts(t)
        msg = stamp_msg(t)
        assert isinstance(msg, Time) and (msg.sec, msg.nanosec) == (sec, nanosec)
        assert stamp_dict(t) == {'sec': sec, 'nanosec': nanosec}
        assert stamp_seconds(msg) == stamp_seconds(stamp_dict(t)) == pytest.approx(t, abs=5e-10)
        assert stamp_ns(msg) == stamp_ns(stamp_dict(t)) == int(round(t * 1e9))
        assert stamp_parts_ns(stamp_ns(msg)) == (sec, nanosec)
        assert stamp_dict_ns(stamp_ns(msg)) == stamp_dict(t)
    # the float the pre-existing readers computed (sec + nanosec * 1e-9), so results do not move
    assert stamp_seconds(Time(sec=3, nanosec=7)) == 3 + 7 * 1e-9
