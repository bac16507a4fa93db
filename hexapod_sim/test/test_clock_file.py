"""The clock file: the sim time a process reached, readable by another process after a SIGKILL."""
import signal
import subprocess
import sys

from hexapod_sim.bagio.clock_file import ClockFile, read_clock_file


def test_a_clock_file_holds_the_last_time_set(tmp_path):
    path = tmp_path / 'c.clock'
    assert read_clock_file(path) is None                  # no file
    clock = ClockFile(path)
    assert read_clock_file(path) is None                  # nothing written yet
    for t in (0.001, 2.5, 17.25):
        clock.set(t)
        assert read_clock_file(path) == t
    clock.close()
    (tmp_path / 'short').write_bytes(b'\x00' * 3)
    assert read_clock_file(tmp_path / 'short') is None
    assert read_clock_file(tmp_path) is None              # a folder: not a clock


def test_a_killed_process_leaves_its_last_time_in_the_file(tmp_path):
    path = tmp_path / 'c.clock'
    code = ('import os, signal, sys; from hexapod_sim.bagio.clock_file import ClockFile; c = ClockFile(sys.argv[1]); '
            '[c.set(i * 0.001) for i in range(12346)]; os.kill(os.getpid(), signal.SIGKILL)')
    p = subprocess.run([sys.executable, '-c', code, str(path)], timeout=60)
    assert p.returncode == -signal.SIGKILL
    assert read_clock_file(path) == 12345 * 0.001
