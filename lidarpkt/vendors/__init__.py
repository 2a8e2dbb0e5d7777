"""One folder per sensor family: ``velodyne``, ``ouster``, ``hesai``."""
