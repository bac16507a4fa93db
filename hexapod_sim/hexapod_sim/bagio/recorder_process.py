"""A :class:`~hexapod_sim.bagio.recorder.Recorder` in a child process, fed through a pipe. No rclpy.

:class:`RecorderProcess`: the sim node's callers (the executor thread that steps the sim and answers
the bus, the controller's thread in the composed robot) only enqueue the message objects they made
anyway; a thread of the node pickles them to the child in one batch every :data:`SEND_PERIOD_S`
(not per message: a thread woken per message takes the interpreter from the executor thread each
time), and the child converts and writes them. The conversion, the bag writer and its periodic
flush (an eighth to a third of a core for the sim's ~3,000 messages a second, most of it pure
Python) then do not hold the node's interpreter lock; as a thread of the node they did, and with
the machine loaded the sim published its reads late and in bursts (docs/architecture.md, "Recording
in the sim node"). :class:`~hexapod_sim.bagio.recorder.RecorderThread` (the same in a thread of the
node) stays for the Foxglove live view, which serves from the node's process. In either, the callers
never wait for the conversion, the bag writer or its periodic flush. The bus transactions of the
composed robot no longer include the bag's writes, and the sim node's recording callbacks no longer
wait for a transaction to end (they took the sim's lock). What had kept the composed robot from real
time while recording was its executor (README.md, hexapod_locomotion.nodes.robot): rclpy's
MultiThreadedExecutor (Jazzy) busy-loops while a callback waits in its thread pool
(ros2/rclpy#1452), and the recording subscriptions make several hundred callbacks a second.
"""
from __future__ import annotations

import collections
import math
import os
import pickle
import signal
import struct
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

from hexapod_model.description import Robot
from hexapod_sim.bagio import BagError
from hexapod_sim.bagio.recorder import FLUSH_PERIOD_S, MAX_QUEUED, Recorder, _QueuedWrites, _write_queued, one_line

SEND_PERIOD_S = 0.02          # RecorderProcess: the sender hands the queue to the child this often...
SEND_BATCH = 1_000            # ... or when this many messages wait
# [s] of log time the caller may run ahead of the messages the child has written: a killed caller loses at
# most this, a power cut at most this and the writer's unflushed FLUSH_PERIOD_S, under a second in all
MAX_LAG_S = 0.4
assert MAX_LAG_S + FLUSH_PERIOD_S < 1.0

_FRAME = struct.Struct('<I')


def _send_frame(stream, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_FRAME.pack(len(data)))
    stream.write(data)
    stream.flush()


def _read_frame(stream):
    """The next object on ``stream``; EOFError at its end."""
    head = stream.read(_FRAME.size)
    if len(head) < _FRAME.size:
        raise EOFError
    n = _FRAME.unpack(head)[0]
    data = stream.read(n)
    if len(data) < n:
        raise EOFError
    return pickle.loads(data)


class RecorderProcess(_QueuedWrites):
    """:class:`RecorderThread`'s interface with the :class:`Recorder` in a child process (thread safe).

    The child is a new interpreter (``python -c``, this interpreter's ``sys.path``) in a process
    group of its own, so a Ctrl-C in the terminal reaches only the node, which then closes the recording
    with everything enqueued before. A bag that cannot be created raises :class:`BagError` here,
    as :class:`Recorder` does. :meth:`write` and :meth:`write_tf_if_due` only enqueue (the objects
    must not change afterwards); a sender thread pickles what is queued in one batch and writes it
    to the child's pipe, which releases the interpreter lock while the child catches up. At most
    ``max_queued`` messages wait; beyond that :meth:`write` waits, as :class:`RecorderThread`'s
    does. :meth:`write` also waits while its message is more than ``max_lag_s`` of log time ahead of
    the last one the child has written (None: no such bound), so that a hard kill of the caller loses
    at most that much of the recording, however loaded the machine: the child writes everything
    handed to it, even once the caller is gone. A write the child cannot make (disk full) ends the
    recording with one line, kept in :attr:`error` and handed once to ``on_error`` from a reader
    thread; a child that ends unexpectedly is reported the same way. :meth:`close` sends what is
    queued, lets the child close the bag and waits for it: :attr:`count` is then the number of
    messages in the bag, and :attr:`close_error` says why the bag could not be closed, if so.
    """

    _wake_at = SEND_BATCH       # the sender takes batches: woken at a full one, else at its period

    def __init__(self, bag_dir: str | os.PathLike, robot: Robot | None = None, on_error=None,
                 max_queued: int = MAX_QUEUED, max_lag_s: float | None = MAX_LAG_S, **recorder_kw: Any):
        if max_queued < 1:
            raise ValueError(f'max_queued must be >= 1, got {max_queued}')
        if max_lag_s is not None and not max_lag_s > 0:
            raise ValueError(f'max_lag_s must be > 0 or None, got {max_lag_s}')
        self._max_lag_s = max_lag_s
        self._unwritten = 0                     # messages queued, in the pipe or in the child's hands
        self._written_t_s = -math.inf           # log time of the last message the child has written
        self.path = Path(bag_dir)
        self.on_error = on_error
        self.error: str | None = None
        self.close_error: str | None = None
        self._count = 0
        self._items: collections.deque = collections.deque()
        self._max = max_queued
        self._closed = False
        self._ended = False                     # the sender has stopped (closed, or the child is gone)
        lock = threading.Lock()
        self._not_empty = threading.Condition(lock)
        self._not_full = threading.Condition(lock)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        self._proc = subprocess.Popen(
            [sys.executable, '-c', 'from hexapod_sim.bagio.recorder_process import recorder_process_main; recorder_process_main()'],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, process_group=0)
        try:
            _send_frame(self._proc.stdin, (str(self.path), robot, recorder_kw))
            kind, text = _read_frame(self._proc.stdout)
        except (EOFError, OSError):
            kind, text = 'fail', f'the recorder process ended at start (exit code {self._proc.wait()})'
        if kind != 'ready':
            self._proc.stdin.close()
            self._proc.wait()
            raise BagError(text)
        self._sender = threading.Thread(target=self._send, name='recorder-sender', daemon=True)
        self._reader = threading.Thread(target=self._read, name='recorder-reader', daemon=True)
        self._sender.start()
        self._reader.start()

    @property
    def count(self) -> int:
        """Messages written so far (the child reports after each batch; final once :meth:`close` returned)."""
        return self._count


    def _behind(self, t_s: float) -> bool:
        if self._max_lag_s is None or self._unwritten == 0:     # (a jump in log time waits for nothing)
            return False
        return t_s - self._written_t_s > self._max_lag_s

    def _queued(self, t_s: float) -> None:
        if self._unwritten == 0:                # the lag counts from the first message not yet written
            self._written_t_s = t_s
        self._unwritten += 1

    def _send(self) -> None:
        try:
            while True:
                with self._not_empty:
                    # every SEND_PERIOD_S (or at SEND_BATCH messages), not per message: a thread woken per
                    # message takes the interpreter from the executor thread each time it wants it back
                    self._not_empty.wait_for(lambda: len(self._items) >= SEND_BATCH or self._closed,
                                             timeout=SEND_PERIOD_S)
                    batch = list(self._items)
                    self._items.clear()
                    self._not_full.notify_all()
                    closing = self._closed
                if batch:
                    _send_frame(self._proc.stdin, batch)
                if closing:
                    self._proc.stdin.close()         # end of input: the child closes the bag
                    return
        except (OSError, ValueError, pickle.PicklingError) as exc:
            self._fail(f'cannot hand messages to the recorder process: {one_line(exc)}')
        finally:
            with self._not_full:
                self._ended = True
                self._not_full.notify_all()

    def _read(self) -> None:
        """Reports of the child: a write that failed, and at the end the bag's count and close error."""
        while True:
            try:
                kind, *rest = _read_frame(self._proc.stdout)
            except (EOFError, OSError, pickle.UnpicklingError):
                if not self._closed:
                    self._fail(f'the recorder process ended (exit code {self._proc.wait()})')
                return
            if kind == 'count':
                self._count, n_items, t_s = rest
                with self._not_full:
                    self._unwritten -= n_items
                    if t_s is not None:
                        self._written_t_s = t_s
                    self._not_full.notify_all()
            elif kind == 'error':
                self._fail(rest[0])
            elif kind == 'closed':
                self._count, self.close_error = rest
                return

    def _fail(self, text: str) -> None:
        if self.error is not None:
            return
        self.error = text
        with self._not_full:
            self._items.clear()
            self._not_full.notify_all()
        self._report(text)

    def close(self) -> None:
        """Send everything enqueued so far, let the child close the bag, wait for it (idempotent)."""
        if not self._end_queue():
            return
        self._sender.join()
        self._reader.join()
        self._proc.wait()

    def __enter__(self) -> 'RecorderProcess':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def recorder_process_main() -> None:
    """The child of :class:`RecorderProcess`: frames of pickled batches on stdin, reports on stdout."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)        # the node decides when the recording ends
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr                             # nothing else may write into the report pipe
    path, robot, kw = _read_frame(inp)
    try:
        rec = Recorder(path, robot=robot, **kw)
    except Exception as exc:                            # noqa: BLE001 - the parent raises it as one line
        _send_frame(out, ('fail', one_line(exc)))
        return
    parent = [True]                                     # the parent still reads the reports

    def report(frame) -> None:
        """A report to the parent; once it is gone (killed: the pipe is broken) the bag is still
        written to its end and closed: end of input comes when its last batch has been read."""
        if parent[0]:
            try:
                _send_frame(out, frame)
            except OSError:
                parent[0] = False
    report(('ready', None))
    failed = False
    while True:
        try:
            batch = _read_frame(inp)
        except (EOFError, OSError, pickle.UnpicklingError):     # a killed parent can leave half a frame
            break
        for item in batch:
            if failed:
                break
            error = _write_queued(rec, item)
            if error is not None:
                failed = True
                report(('error', error))
        report(('count', rec.count, len(batch), batch[-1][-1] if batch else None))   # and the log time written up to
    close_error = None
    try:
        rec.close()
    except Exception as exc:                            # noqa: BLE001 - the parent reports it in its closing line
        close_error = one_line(exc)
    report(('closed', rec.count, close_error))
