"""The one IMU shape: samples and series convert into each other without loss."""
import numpy as np
import pytest

from hexapod_model.imu import ImuReading, ImuSeries


def _readings(n=5, quat=True):
    rng = np.random.default_rng(3)
    return [ImuReading(0.0025 * k, rng.normal(size=4) if quat else None, rng.normal(size=3), rng.normal(size=3))
            for k in range(n)]


@pytest.mark.parametrize('quat', [True, False])
def test_readings_to_series_and_back_are_the_same_samples(quat):
    readings = _readings(quat=quat)
    series = ImuSeries.from_readings(readings)
    assert len(series) == 5 and series.accel.shape == series.gyro.shape == (5, 3)
    assert (series.quat_wxyz is None) is (not quat)
    for i, r in enumerate(readings):
        back = series.reading(i)
        assert back.t_s == r.t_s
        for k in ('quat_wxyz', 'accel', 'gyro'):
            a, b = getattr(back, k), getattr(r, k)
            assert (a is None and b is None) or np.array_equal(a, b)
    assert len(ImuSeries.from_readings([])) == 0


def test_a_series_selects_and_shifts_its_samples_as_rows():
    s = ImuSeries.from_readings(_readings())
    s = ImuSeries(s.t_s, s.accel.copy(), s.gyro, s.quat_wxyz)
    s.accel[1, 2] = np.nan
    ok = s.take(s.finite())
    assert len(ok) == 4 and np.array_equal(ok.t_s, np.delete(s.t_s, 1)) and ok.quat_wxyz.shape == (4, 4)
    assert np.array_equal(ok.shifted(1.0).t_s, ok.t_s - 1.0)


def test_a_series_of_mismatched_rows_or_mixed_samples_is_refused():
    with pytest.raises(ValueError, match='accel'):
        ImuSeries(np.zeros(3), np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match='orientation'):
        ImuSeries.from_readings(_readings(2) + _readings(1, quat=False))
