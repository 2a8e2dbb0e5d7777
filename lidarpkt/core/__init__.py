"""The model every other layer speaks: frames and the sensor description (``frame``), packets and
batches (``packet``), IMU samples (``imu``), the decoder and stream-counter protocols (``decoder``),
stream kinds (``streams``), drop reasons (``dropped``), the continuity and rotation rules, the
compiled kernels (``kernels``), and two helpers (``lazy`` names, ``readahead`` threads and their
warnings). It imports NumPy and the standard library only."""
