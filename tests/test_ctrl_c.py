"""Ctrl-C in the tools that run for a while (demo, analyse, discrepancy): one line saying what was
kept, exit code 130, no traceback; the demo's bag is closed and readable."""
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from hexapod_model.cli_common import EXIT_INTERRUPTED
from hexapod_testing import installed_executable

ROOT = Path(__file__).resolve().parents[1]


def test_demo_ctrl_c_keeps_a_readable_bag(tmp_path):
    from hexapod_sim.bagio.reader import BagReader
    bag = tmp_path / 'walk'
    env = dict(os.environ, PYTHONUNBUFFERED='1', HEXAPOD_EXE='demo', HEXAPOD_PROG='./hexapod demo')
    proc = subprocess.Popen([installed_executable('hexapod_locomotion', 'demo'), '--terrain', 'flat', '--record', str(bag)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, env=env, cwd=tmp_path)
    err = []

    def read():
        while chunk := os.read(proc.stderr.fileno(), 4096):
            err.append(chunk)
    reader_thread = threading.Thread(target=read, daemon=True)
    reader_thread.start()
    try:
        # the progress bar shows the simulated time once the walk is under way (a failure bound only)
        deadline = time.monotonic() + 300
        while b'sim ' not in b''.join(err) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None and b'sim ' in b''.join(err), b''.join(err).decode(errors='replace')
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    reader_thread.join(10)
    text = b''.join(err).decode(errors='replace')
    assert proc.returncode == EXIT_INTERRUPTED, text
    assert 'Traceback' not in text and 'KeyboardInterrupt' not in text, text
    lines = [ln for ln in text.replace('\r', '\n').splitlines() if ln.strip() and not ln.startswith('walking')]
    assert lines == [f'./hexapod demo: interrupted (Ctrl-C); bag {bag} closed, with the walk so far'], text
    reader = BagReader(bag)
    topics = {m.topic for m in reader.messages()}
    assert '/joint_states' in topics and '/ground_detection' in topics, topics
    assert reader.warnings == [], reader.warnings           # closed properly: no recovery needed


def _tool(name):
    """(main, module attribute its work goes through, arguments, what its one line ends with)."""
    if name == 'analyse':
        from hexapod_locomotion.trials import analyse
        return analyse, 'rerun_detectors', [str(ROOT / 'bags' / 'tripod_blocks_fixed'), '--json', 'a/r.json'], \
            'analyse: interrupted (Ctrl-C); nothing written'
    if name == 'discrepancy':
        from hexapod_sim.discrepancy import cli
        return cli, 'analyse', [str(ROOT / 'bags' / 'discrepancy_demo'), '--json', 'out/d.json'], \
            'discrepancy: interrupted (Ctrl-C)'
    from hexapod_locomotion.bench import discrepancy_bench
    return discrepancy_bench, 'run', ['--cases', 'clean', '--json', 'r.json'], \
        'discrepancy_bench: interrupted (Ctrl-C); nothing written'


@pytest.mark.parametrize('name', ['analyse', 'discrepancy', 'discrepancy_bench'])
def test_ctrl_c_in_a_tool_is_one_line_and_leaves_nothing(monkeypatch, capsys, tmp_path, name):
    module, attr, args, line = _tool(name)

    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(module, attr, interrupted)
    monkeypatch.chdir(tmp_path)
    rc = module.main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_INTERRUPTED
    assert len(err) == 1 and err[0].endswith(line), err
    assert list(tmp_path.iterdir()) == []
