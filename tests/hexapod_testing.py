"""Helpers shared by the packages' tests that start ROS nodes (one home instead of a copy per file).

Here rather than in a root ``conftest.py``: the test folders are ament_python ``test/`` folders
without ``__init__.py`` that ``colcon test`` runs per package, where a conftest at the workspace
root is not seen; an installed module is importable from every package's tests either way.
rclpy and ament_index are imported inside the functions, so importing this module costs nothing.

Every helper keeps DDS on loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and on the
domain the calling test file chose for itself.
"""
from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import threading
import time
from typing import Callable, Iterator


def node_env(domain_id: int, **extra: str) -> dict:
    """Environment for a node process of a test: its own domain, loopback only, unbuffered output."""
    return dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                PYTHONUNBUFFERED='1', **extra)


def stop_process(proc: subprocess.Popen, sig: int = signal.SIGINT, timeout_s: float = 20.0) -> tuple[int, str]:
    """Send ``sig`` (Ctrl-C by default) unless the process has ended, wait up to ``timeout_s``, kill it
    if it does not stop; returns (return code, its whole output)."""
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return proc.returncode, out


def installed_executable(pkg: str, name: str) -> str:
    """Path of an installed console script, as ``ros2 run PKG NAME`` finds it."""
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix(pkg), 'lib', pkg, name)


@contextlib.contextmanager
def ros_probe(name: str, domain_id: int) -> Iterator[tuple]:
    """A probe node in a private context on ``domain_id`` with its own single-threaded executor:
    yields ``(node, executor)``; everything is shut down on exit. Use it in a module fixture::

        @pytest.fixture(scope='module')
        def ros():
            with ros_probe('my_test', DOMAIN_ID) as probe:
                yield probe
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    node = rclpy.create_node(name, context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    try:
        yield node, ex
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def spin_until(ex, cond: Callable[[], bool], timeout_s: float, what: str = 'a condition',
               alive: Callable[[], None] | None = None) -> None:
    """Spin ``ex`` until ``cond()`` holds. ``timeout_s`` is a failure bound only (a loaded machine
    may be slow; the test asserts on what arrived, never on how long it took). ``alive()`` is
    called between spins and may raise (e.g. when a node process under test has died)."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if alive is not None:
            alive()
        if time.monotonic() > deadline:
            raise AssertionError(f'timed out after {timeout_s:g} s waiting for {what}')
        ex.spin_once(timeout_sec=0.05)


def logged(text: str, kind, joint: str | None = None) -> list[str]:
    """The lines of a node's log that report a driver event of ``kind`` (a
    ``hexapod_driver.bus.EventKind``: logged as ``[tag] text``), about ``joint`` if given."""
    mark = f'[{kind.tag}] ' + (f'{joint} (id ' if joint else '')
    return [ln for ln in text.splitlines() if mark in ln]


class ProcessOutput:
    """A started process's stdout (stderr merged into it), read line by line in the background."""

    def __init__(self, proc: subprocess.Popen):
        self.lines: list[str] = []
        self._t = threading.Thread(target=lambda: [self.lines.append(ln) for ln in proc.stdout], daemon=True)
        self._t.start()

    def text(self) -> str:
        return ''.join(self.lines)

    def finish(self, proc: subprocess.Popen, sig=signal.SIGINT, timeout: float = 30.0) -> tuple[int, str]:
        """Stop the process with ``sig`` (if it still runs), killing it after ``timeout`` (a line says so);
        -> (exit code, everything it printed)."""
        if proc.poll() is None:
            proc.send_signal(sig)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            self.lines.append(f'<<killed: no exit within {timeout} s of {sig!r}>>\n')
        self._t.join(timeout=5.0)
        return proc.returncode, self.text()
