"""lidarpkt recorder: recording live sensors, replay and serial GPS, as a Python API.

Modules: :mod:`lidarpkt.recorder.record` (:func:`~lidarpkt.recorder.record.record`: live packets to
MCAP), :mod:`lidarpkt.recorder.frames` (frames decoded off the receive path while recording),
:mod:`lidarpkt.recorder.replay` (a capture sent over UDP at its own pace), :mod:`lidarpkt.recorder.gps`
(serial NMEA). Their verbs are :mod:`lidarpkt.cli.record` and :mod:`lidarpkt.cli.replay`. The MCAP
writer, its schemas, point clouds and the packets → topics sink live in :mod:`lidarpkt.writers.mcap`;
the live UDP packet source in :mod:`lidarpkt.containers.udp`.
"""
