"""Recordings of runs: MCAP files any tool opens (Foxglove too), read back typed, summarised.

- :mod:`common.recording.schema`: the channels and their record types (JSON + jsonschema)
- :mod:`common.recording.writer`: :class:`RecordingWriter`, one run's file
- :mod:`common.recording.reader`: :func:`read_recording` -> :class:`Recording`
- :mod:`common.recording.summary`: :func:`summarize` -> :class:`Summary` (``wart report``)
- :mod:`common.recording.compare`: :func:`compare` two runs -> :class:`Comparison` (sim beside
  real, ``wart report A --against B``)
- :mod:`common.recording.store`: the per-user directory of recordings, with retention
- :mod:`common.recording.replay`: :class:`Timeline` (what was, at a cursor time) and
  :class:`Player` (play, pause, speed): the page's replay and ``wart replay``
"""

from common.recording.reader import Recording, RecordingError, Stamped, read_recording
from common.recording.summary import Summary, summarize
from common.recording.writer import RecordingWriter

__all__ = [
    "Recording",
    "RecordingError",
    "RecordingWriter",
    "Stamped",
    "Summary",
    "read_recording",
    "summarize",
]
