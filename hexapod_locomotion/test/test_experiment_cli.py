"""./hexapod experiment: the quality table keeps the failing cells."""
from hexapod_locomotion.trials.experiments import format_quality


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


# ------------------------------------------------------------------------------- Ctrl-C on a run
import json  # noqa: E402
import os  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402

import pytest  # noqa: E402

STOP_BOUND_S = 10.0        # the requirement is 2 s; the bound leaves room for a loaded machine


class Run:
    """``experiment`` as the installed console script, its stderr (progress bars) collected."""

    def __init__(self, *args):
        from hexapod_testing import installed_executable
        self.proc = subprocess.Popen([installed_executable('hexapod_locomotion', 'experiment'), *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED='1'))
        self.err = b''
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        while chunk := os.read(self.proc.stderr.fileno(), 4096):
            self.err += chunk

    def wait_for(self, text: str, timeout_s: float = 300.0):
        deadline = time.monotonic() + timeout_s
        while text.encode() not in self.err:
            assert self.proc.poll() is None, self.err.decode(errors='replace')
            assert time.monotonic() < deadline, f'no {text!r} in {self.err.decode(errors="replace")}'
            time.sleep(0.05)

    def workers(self) -> list[int]:
        out = []
        for d in os.listdir('/proc'):
            if d.isdigit():
                try:
                    with open(f'/proc/{d}/stat') as f:
                        if int(f.read().rsplit(')', 1)[1].split()[1]) == self.proc.pid:
                            out.append(int(d))
                except (OSError, IndexError, ValueError):
                    pass
        return out

    def interrupt(self) -> float:
        """Ctrl-C; seconds until the process had ended."""
        t0 = time.monotonic()
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=120)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
        took = time.monotonic() - t0
        time.sleep(0.2)              # the reader thread takes the last bytes
        return took

    def last_lines(self) -> list[str]:
        return [ln for ln in self.err.decode(errors='replace').replace('\r', '\n').splitlines()
                if ln.strip() and 'trials:' not in ln]


@pytest.mark.realtime
def test_ctrl_c_stops_at_once_and_leaves_nothing_when_no_trial_finished(tmp_path):
    out = tmp_path / 'x'
    run = Run('table4', '--trials', '1', '--duration', '30', '--jobs', '2', '--out', str(out))
    run.wait_for('mockup trials:')
    deadline = time.monotonic() + 60
    while len(run.workers()) < 2:                # both pool workers have started their trials
        assert run.proc.poll() is None and time.monotonic() < deadline, run.err.decode(errors='replace')
        time.sleep(0.05)
    workers = run.workers()
    took = run.interrupt()
    err = run.err.decode(errors='replace')
    assert took < STOP_BOUND_S, f'took {took:.1f} s to stop'
    assert run.proc.returncode == 130, err
    assert 'Traceback' not in err, err
    lines = run.last_lines()
    assert len(lines) == 1, lines
    if 'nothing written' in lines[0]:            # a 30 s trial takes longer than the start-up
        assert not out.exists(), list(out.iterdir())
    else:
        assert 'kept' in lines[0] and (out / 'table4.json').is_file(), lines
    assert not [p for p in workers if os.path.exists(f'/proc/{p}')], 'worker processes left running'


@pytest.mark.realtime
def test_ctrl_c_keeps_and_names_the_finished_trials(tmp_path):
    out = tmp_path / 'x'
    run = Run('table4', '--trials', '1', '--duration', '1', '--jobs', '2', '--out', str(out))
    run.wait_for('1/18')
    took = run.interrupt()
    err = run.err.decode(errors='replace')
    assert took < STOP_BOUND_S, f'took {took:.1f} s to stop'
    assert run.proc.returncode == 130 and 'Traceback' not in err, err
    lines = run.last_lines()
    assert len(lines) == 1 and 'interrupted (Ctrl-C); kept ' in lines[0] and str(out / 'table4.json') in lines[0], lines
    report = json.loads((out / 'table4.json').read_text())
    kept = report['interrupted_stage_results']
    assert report['interrupted'] and 1 <= len(kept) < 18
    assert f'kept {len(kept)} finished trial(s) ({len(kept)} of 18 mockup trials)' in lines[0], lines
    assert all(r['config']['gait'] in ('tripod', 'tetrapod', 'pentapod') for r in kept)


def test_table4_cells_and_the_course_correction_are_chosen():
    """Table 4's trials walk the paper's open loop unless --heading-correction; --variants picks the cells."""
    from hexapod_locomotion.trials.experiments import main, table4_configs
    cfgs = table4_configs(2, 30.0, 'mockup')
    assert len(cfgs) == 3 * 2 * 3 * 2 and not any(c.heading_correction for c in cfgs)
    on = table4_configs(1, 30.0, 'mockup', variants=('adaptive',), heading_correction=True)
    assert len(on) == 3 * 2 and all(c.heading_correction and c.detector == 'adaptive' and c.approach_rate == 1.0
                                    for c in on)
    with pytest.raises(SystemExit):
        main(['table4', '--variants', 'best'])


@pytest.mark.parametrize('value,why', [('-0.01', 'must be a finite number >= 0, got -0.01'),
                                       ('nan', 'must be a finite number >= 0, got nan'),
                                       ('wide', "expected a number, got 'wide'")])
def test_support_margin_is_refused_by_its_parameter_declaration_in_one_line(capsys, value, why):
    """--support-margin takes its range from locomotion_node's support_margin_m: the same reason."""
    from hexapod_locomotion.trials.experiments import main
    with pytest.raises(SystemExit) as exc:
        main(['table4', '--support-margin', value])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f'argument --support-margin: {why}' in err[0], err
