"""The vendor layer: one folder per sensor family (``velodyne``, ``ouster``, ``hesai``), each exporting its
:class:`~lidarpkt.core.vendor.Vendor` record as ``VENDOR``, and the registry of them (:mod:`.registry`)."""
