"""The terrain timeline of a bag and its confusion against a label file (``./hexapod analyse BAG
[--labels FILE]``). No rclpy.

The classes come from the bag's ``/terrain`` (what terrain_node published on the robot); a bag
without it is classed offline from its recorded streams with the packaged model (or ``model``).
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from hexapod_locomotion.core.terrain_model import DEFAULT_MODEL, TerrainModel, accuracy, confusion, confusion_lines
from hexapod_locomotion.trials.terrain_data import UNLABELLED, TerrainDataError, bag_cycles, cycle_labels, read_labels
from hexapod_model.contract import TERRAIN, stamp_seconds, topic_key


class _Cycle:
    def __init__(self, t0, t1, terrain, confidence):
        self.t_start_s, self.t_end_s, self.terrain, self.confidence = t0, t1, terrain, confidence


def bag_terrain(path, robot, model_path=None) -> tuple[list[_Cycle], str, tuple[str, ...] | None]:
    """(cycles with their class, where the classes came from, the model's classes or None)."""
    from hexapod_sim.bagio import BagReader, BagWarning
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', BagWarning)
        reader = BagReader(path)
        names = [t for t in reader.topics() if topic_key(t) == TERRAIN]
        cycles = [_Cycle(stamp_seconds(m.cycle_start), stamp_seconds(m.header.stamp), str(m.terrain), float(m.confidence))
                  for _n, _ty, _t, m in reader.messages(topics=names)] if names else []
    if cycles:
        return cycles, f'/{TERRAIN} as recorded', None
    model = TerrainModel.load(model_path or DEFAULT_MODEL)
    d = bag_cycles(path, robot, labels=False)
    pred, conf = model.predict(d['X'])
    cycles = [_Cycle(t0, t1, str(p), float(c)) for t0, t1, p, c in zip(d['t_start'], d['t_end'], pred, conf)]
    return cycles, f'classed offline by {model_path or DEFAULT_MODEL}', model.classes


def report_lines(path, robot, labels: str | None = None, model_path=None) -> list[str]:
    cycles, source, model_classes = bag_terrain(path, robot, model_path)
    from hexapod_sim.physics.terrain_classes import CLASSES
    known = tuple(dict.fromkeys([*(model_classes or ()), *CLASSES, *(c.terrain for c in cycles)]))
    intervals = read_labels(labels, known) if labels else None
    lines = [f'terrain ({source}): {len(cycles)} gait cycles']
    run = []
    for c in cycles + [None]:
        if run and (c is None or c.terrain != run[0].terrain):
            conf = np.mean([r.confidence for r in run])
            lines.append(f'  {run[0].t_start_s:8.2f} - {run[-1].t_end_s:8.2f} s  {run[0].terrain:10s} '
                         f'{len(run):3d} cycle(s), mean confidence {100 * conf:.0f} %')
            run = []
        if c is not None:
            run.append(c)
    if intervals is not None:
        truth = cycle_labels(cycles, intervals)
        pairs = [(t, c.terrain) for t, c in zip(truth, cycles) if t != UNLABELLED]
        if not pairs:
            raise TerrainDataError(f'{labels}: no gait cycle of the bag lies within one labelled interval')
        classes = tuple(dict.fromkeys([*(model_classes or ()), *sorted({t for t, _ in pairs} | {p for _, p in pairs})]))
        m = confusion([t for t, _ in pairs], [p for _, p in pairs], classes)
        lines.append(f'against {Path(labels).name}: {100 * accuracy(m):.1f} % of {int(m.sum())} labelled cycles '
                     f'({len(cycles) - len(pairs)} not scored: across a boundary or unlabelled)')
        lines += ['  ' + x for x in confusion_lines(m, classes)]
    return lines
