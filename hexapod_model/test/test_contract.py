"""Header stamps of the recording contract."""
from hexapod_model.contract import stamp_parts


def test_stamp_parts_carries_into_seconds():
    assert stamp_parts(12.000345) == (12, 345000)
    assert stamp_parts(1.9999999999) == (2, 0)          # rounds up into the next second, not (1, 0)
    assert stamp_parts(0.0) == (0, 0)
