"""Header stamps of the recording contract."""
from hexapod_model import contract
from hexapod_model.contract import stamp_parts


def test_stamp_parts_carries_into_seconds():
    assert stamp_parts(12.000345) == (12, 345000)
    assert stamp_parts(1.9999999999) == (2, 0)          # rounds up into the next second, not (1, 0)
    assert stamp_parts(0.0) == (0, 0)


def test_topic_names_are_relative_so_the_stack_runs_under_a_namespace():
    names = [v for k, v in vars(contract).items() if k.isupper() and isinstance(v, str)]
    assert len(names) >= 16
    assert [n for n in names if n.startswith('/')] == [contract.CLOCK]     # use_sim_time listens on /clock
    assert contract.topic_key('/joint_states') == contract.topic_key('joint_states') == contract.JOINT_STATES
    assert contract.bag_topic(contract.SIM_TRUTH_POSE) == '/sim/body_pose'
    assert contract.bag_topic(contract.CLOCK) == '/clock'
