"""lidarpkt recorder: live UDP capture, replay, serial GPS and MCAP writing.

Modules: :mod:`recorder.schemas` (ROS 2 messages, topics, QoS, CDR codecs),
:mod:`recorder.mcap_writer` (the MCAP file: time-sized chunks, rotation),
:mod:`recorder.sink` (packets → topics, shared by ``record`` and ``decode``),
:mod:`recorder.streams` (stream kinds and loss accounting), :mod:`recorder.pointcloud`
(frames as PointCloud2 / Image), :mod:`recorder.capture` (receive thread),
:mod:`recorder.gps` (serial NMEA), and the verbs :mod:`recorder.record`,
:mod:`recorder.replay`, :mod:`recorder.decode`.
"""
