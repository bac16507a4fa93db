"""Windowed bus timing statistics (T_com of reads, duration of writes, failed reads) for the
driver's /bus_timing messages. Thread-safe; no ROS import."""
from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TimingSnapshot:
    reads: int
    failed_reads: int
    t_com_mean_s: float
    t_com_p99_s: float
    t_com_max_s: float
    write_mean_s: float


class TimingStats:
    """Windowed T_com statistics (thread-safe)."""

    def __init__(self, maxlen: int = 100_000):
        self._lock = threading.Lock()
        self._reads: deque[float] = deque(maxlen=maxlen)
        self._writes: deque[float] = deque(maxlen=maxlen)
        self._failed = 0

    def read(self, duration: float) -> None:
        with self._lock:
            self._reads.append(duration)

    def failed(self) -> None:
        with self._lock:
            self._failed += 1

    def write(self, duration: float) -> None:
        with self._lock:
            self._writes.append(duration)

    def snapshot(self, reset: bool = True) -> TimingSnapshot:
        with self._lock:
            r = np.asarray(self._reads, dtype=float)
            w = np.asarray(self._writes, dtype=float)
            failed = self._failed
            if reset:
                self._reads.clear()
                self._writes.clear()
                self._failed = 0
        return TimingSnapshot(
            reads=int(r.size), failed_reads=failed,
            t_com_mean_s=float(r.mean()) if r.size else math.nan,
            t_com_p99_s=float(np.percentile(r, 99)) if r.size else math.nan,
            t_com_max_s=float(r.max()) if r.size else math.nan,
            write_mean_s=float(w.mean()) if w.size else math.nan)
