"""Recordings as MCAP files (``recording.mcap``): written while a run goes, read back as a
``cdpr-recording/1`` recording, converted to and from the CSV directory.

One file holds what the CSV directory holds:

- attachments ``robot.toml`` (the model the controller ran with, as text) and ``meta.toml``
  (the last one written is the meta; :meth:`writer.McapRecordingWriter.update_meta` adds one);
- a metadata record ``cdpr-recording`` with ``format`` and ``columns`` (the CSV header in
  order, JSON list, ``state`` included where the recording has it);
- one JSON channel per column group (:data:`TOPICS`), every message with ``t`` [s] and the
  group's values (``null`` for not measured); all messages of one row share the MCAP
  ``sequence`` (the row index) and ``log_time`` (``t`` in ns, 0 for a negative ``t``);
- ``/supervisor/events`` (``cdpr.SupervisorEvent``), the rows of ``events.csv``;
- for Foxglove: ``/tf`` (``foxglove.FrameTransform``, ``world`` -> ``platform``, the measured
  pose, else the desired one) and ``/scene`` (``foxglove.SceneUpdate``: masts, cables
  coloured by tension, the platform), protobuf encoded by the foxglove SDK.

Chunks are zstd compressed and closed at least every ``flush_s`` seconds by a background
thread, so a file cut short by a crash, SIGKILL or Ctrl-C reads up to its last whole chunk
(:func:`reader.read_mcap` reads such a file and says so).

Modules: :mod:`~bench.mcap.channels` (topics, schemas, a row's messages),
:mod:`~bench.mcap.scene` (``/tf``, ``/scene``), :mod:`~bench.mcap.writer`,
:mod:`~bench.mcap.reader` (and ``cdpr recording info``), :mod:`~bench.mcap.convert` (MCAP <->
CSV directory), :mod:`~bench.mcap.can_tap` (``/can``), :mod:`~bench.mcap.recorders` (the
dry run's and the monitor's recorders), :mod:`~bench.mcap.child` (a real-time run's
writers in a child process), :mod:`~bench.mcap.live` (the Foxglove WebSocket view),
:mod:`~bench.mcap.foxglove_layout` (the shipped Foxglove layout). The package shares its
last name with the ``mcap`` library, which every import here names absolutely.
"""

from bench.mcap.channels import (
    CAN_LOG,
    CAN_TOPIC,
    EVENT_FIELDS,
    EVENTS_TOPIC,
    MCAP_NAME,
    TOPICS,
    layout,
)
from bench.mcap.convert import (
    convert,
    convert_target,
    csv_to_mcap,
    mcap_to_csv,
    read_recording_mcap,
)
from bench.mcap.reader import McapContent, info, mcap_file, read_can_frames, read_mcap
from bench.mcap.writer import McapRecordingWriter

__all__ = ["CAN_LOG", "CAN_TOPIC", "EVENTS_TOPIC", "EVENT_FIELDS", "MCAP_NAME", "TOPICS",
           "McapContent", "McapRecordingWriter", "convert", "convert_target", "csv_to_mcap",
           "info", "layout", "mcap_file", "mcap_to_csv", "read_can_frames", "read_mcap",
           "read_recording_mcap"]
