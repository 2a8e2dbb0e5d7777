"""lidarpkt recorder: live UDP capture, replay, serial GPS and MCAP writing.

The MCAP writer, its schemas and point clouds live in :mod:`lidarpkt.writers.mcap` (the old
names ``recorder.schemas``, ``recorder.mcap_writer``, ``recorder.pointcloud`` still import).
Modules: :mod:`recorder.sink` (packets → topics, shared by ``record`` and ``decode``),
:mod:`recorder.streams` (stream kinds and loss accounting), :mod:`recorder.capture` (receive thread),
:mod:`recorder.gps` (serial NMEA), and the verbs :mod:`recorder.record`,
:mod:`recorder.replay`, :mod:`recorder.decode`.
"""

import lidarpkt  # noqa: E402,F401 - installs the old module paths (lidarpkt._moved)
