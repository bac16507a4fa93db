"""odometry_bench: a straight walk ends at --distance; bad input is one line."""
import json

from hexapod_locomotion.bench.odometry_bench import main


def test_a_walk_ends_at_the_distance_and_the_figures_are_printed(tmp_path, capsys):
    out = tmp_path / 'o.json'
    assert main(['--gaits', 'tripod', '--terrains', 'flat', '--seeds', '1', '--distance', '0.15', '--duration', '30',
                 '--correction', 'on', '--jobs', '1', '--json', str(out)]) == 0
    trial = json.loads(out.read_text())['tripod/flat/on'][0]
    assert 0.15 <= trial['distance_m'] < 0.25          # stopped at the end of the phase that passed 0.15 m
    assert trial['odometry']['imu']['duration_s'] < 10
    printed = capsys.readouterr().out
    assert 'tripod/flat/on' in printed
    legs = trial['odometry']['legs']
    assert f"worst seed 0: {legs['position_error_pct']:5.1f} %" in printed     # the legs-only line below the table
    assert f"{legs['yaw_error_off_ground_deg']:+6.1f} of it while a foot it used was off the ground" in printed


def test_an_unknown_terrain_is_one_line(capsys):
    assert main(['--terrains', 'moon']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'unknown terrain moon' in err
