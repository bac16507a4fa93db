"""The sim time a process has reached, in a file another process can read at any moment (no ROS).

The demo runs its sim in process and publishes no ``/clock``. With ``--clock-file PATH`` it keeps the sim
time it has reached in PATH, 8 bytes (little-endian float64, seconds; NaN before the first update),
through a shared memory map: an update is one store to memory, no system call, and a process stopped
(SIGSTOP) or killed leaves its last value in the file. The kill bench (``bench_kills``) reads it where it
reads ``/clock`` for ``sim_node`` and the composed robot: the data a kill lost is that time minus the
bag's last log time.
"""
from __future__ import annotations

import math
import mmap
import os
import struct
from pathlib import Path

_VALUE = struct.Struct('<d')


class ClockFile:
    """Writes the sim time reached to ``path`` (created or overwritten) with :meth:`set`."""

    def __init__(self, path: str | os.PathLike):
        with open(path, 'w+b') as f:
            f.write(_VALUE.pack(math.nan))
            f.flush()
            self._map = mmap.mmap(f.fileno(), _VALUE.size)

    def set(self, t_s: float) -> None:
        _VALUE.pack_into(self._map, 0, t_s)

    def close(self) -> None:
        self._map.close()


def read_clock_file(path: str | os.PathLike) -> float | None:
    """The sim time last written to ``path`` [s]; None if there is no file or nothing was written yet."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return None
    if len(data) < _VALUE.size:
        return None
    t = _VALUE.unpack_from(data)[0]
    return None if math.isnan(t) else t
