"""MCAP output (ROS 2 profile): :mod:`.writer` (the file: time-sized chunks, rotation), :mod:`.schemas`
(messages, topics, QoS, CDR codecs), :mod:`.pointcloud` (frames as PointCloud2 / Image) and
:mod:`.frames` (the frame writer of :func:`lidarpkt.writers.open_writer`: packets, points, images,
``/tf_static``)."""
