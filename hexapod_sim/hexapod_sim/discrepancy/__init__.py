"""The sim-vs-real discrepancy tool: what does the model leave out of a recording?

1. simulate (:mod:`.simulate`): replay the recorded goals through the nominal model and predict
   every recorded read at its stamp;
2. locate (:mod:`.locate`): per joint and time window, where the recording departs from the
   prediction beyond tick quantization, and in which motion condition;
3. name (:mod:`.effects`, :mod:`.fit`): test a library of candidate physical effects, fitted per
   joint, per leg or for the whole robot, selected on held-out data;
4. model and show (:mod:`.analysis`, :mod:`.report`, :mod:`.plot`): the before/after on held-out
   data, a plot, a plain-language report, and the fitted effects as a robot-description overlay.

Command line: :mod:`.cli` (``discrepancy``); benchmark on concealed sim data: :mod:`.bench`.
Pure numpy/scipy (plus matplotlib for the plot); no rclpy.
"""
from hexapod_sim.discrepancy.analysis import Analysis, analyse
from hexapod_sim.discrepancy.findings import FoundEffect
from hexapod_sim.discrepancy.recording import Recording, RecordingError, load_recording

__all__ = ['Analysis', 'FoundEffect', 'Recording', 'RecordingError', 'analyse', 'load_recording']
