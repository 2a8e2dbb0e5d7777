"""lidarpkt recorder: recording live sensors, replay and serial GPS.

Modules: :mod:`lidarpkt.recorder.gps` (serial NMEA), and the verbs
:mod:`lidarpkt.recorder.record`, :mod:`lidarpkt.recorder.replay`, :mod:`lidarpkt.cli.decode`.
The MCAP writer, its schemas, point clouds and the packets → topics sink live in
:mod:`lidarpkt.writers.mcap`; stream kinds and loss accounting in :mod:`lidarpkt.core.streams`; the live UDP packet source in
:mod:`lidarpkt.containers.udp`.
"""
