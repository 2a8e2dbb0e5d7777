"""lidarpkt recorder: live UDP capture, replay, serial GPS and the packets → MCAP topics sink.

Modules: :mod:`lidarpkt.recorder.sink` (packets → topics, shared by ``record`` and ``decode``),
:mod:`lidarpkt.recorder.streams` (stream kinds and loss accounting), :mod:`lidarpkt.recorder.capture`
(receive thread), :mod:`lidarpkt.recorder.gps` (serial NMEA), and the verbs
:mod:`lidarpkt.recorder.record`, :mod:`lidarpkt.recorder.replay`, :mod:`lidarpkt.recorder.decode`.
The MCAP writer, its schemas and point clouds live in :mod:`lidarpkt.writers.mcap`.
"""
