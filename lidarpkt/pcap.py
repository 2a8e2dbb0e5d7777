"""Compatibility name: ``lidarpkt.pcap`` is :mod:`lidarpkt.sources.pcap_reader` (the same module object).

The pcap/pcapng reader was split into the packet-source layer, :mod:`lidarpkt.sources`. This name
stays the module itself, not a copy of its names, so that ``lidarpkt.pcap.X = ...`` (the tests set
the block and chunk sizes) changes what the reader uses.
"""

import sys

from .sources import pcap_reader as _pcap_reader

sys.modules[__name__] = _pcap_reader
