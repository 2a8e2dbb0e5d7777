"""The model every other layer speaks: frames and their points (``frame``), the sensor description
(``sensor``), the column grid and (de)staggering (``grid``), frames in sequence (``sequence``: the readers'
iterator, stacks), packets and batches (``packet``), IMU samples (``imu``), NMEA sentences (``nmea``), the
decoder and stream-counter protocols (``decoder``), stream kinds and what a read saw (``streams``), drop
reasons (``dropped``), what lidarpkt knows of a vendor (``vendor``: the record each vendor package
exports), ROS topics (``ros``), the continuity, rotation and dual-return rules (``continuity``,
``rotation``, ``dual``), the compiled kernels (``kernels``), and two helpers (``lazy`` names,
``readahead`` threads and their warnings). It imports NumPy and the standard library only."""
