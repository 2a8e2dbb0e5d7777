"""Compatibility name: the MCAP and ROS bag reader lives in :mod:`lidarpkt.sources.bags`."""

from .sources.bags import *  # noqa: F401,F403
from .sources.bags import BagReader, MAX_MCAP_CHUNK_BYTES, MESSAGE_DEFINITIONS, OUSTER_METADATA_TOPICS  # noqa: F401
