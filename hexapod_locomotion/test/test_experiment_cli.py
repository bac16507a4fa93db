"""./hexapod experiment: the quality table keeps the failing cells."""
from hexapod_locomotion.experiments import format_quality


def _result(gait, detector, delay, detected):
    stat = {'median': 0.03, 'p90': 0.04}
    det = {'delay_s': stat if delay else None, 'delay_control_periods': stat if delay else None,
           'femur_torque_at_stop_nm': stat, 'peak_femur_torque_nm': stat, 'command_overshoot_m': stat,
           'detected': detected, 'premature_stops': 0, 'missed_contacts': 7}
    return {'config': {'gait': gait, 't_des_s': 1.0, 'detector': detector}, 'detection': det}


def test_quality_table_keeps_cells_without_a_delay():
    text = format_quality([_result('tripod', 'adaptive', True, 30), _result('tripod', 'fixed', False, 0)])
    rows = [line for line in text.splitlines() if line.startswith('tripod')]
    assert len(rows) == 2
    fixed = next(r for r in rows if ' fixed ' in r)
    assert '(0 contacts detected)' in fixed and ' - ' in fixed and fixed.rstrip().split()[-4] == '7'
    assert '(30 contacts detected)' in next(r for r in rows if 'adaptive' in r)
