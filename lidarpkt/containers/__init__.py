"""The packet-source layer: from a capture file to batches of UDP payloads, and segments of a capture.

=================  ===========================================================================
``magic``          file magic, in one place: which container a file is (:func:`container_kind`)
``protocol``       :class:`PacketSource` and :func:`open_packet_source`, used by every caller
``pcap_reader``    :class:`PcapReader`, the pcap/pcapng reader that wires the modules below
``read_stats``     :class:`ReadStats`: what a pass of the reader found (records, datagrams, damage)
``pcap_walk``      classic pcap: blocks of the file, the walk over record headers in chunks
``pcapng_walk``    pcapng: the walk over sections, interfaces and packet blocks in chunks
``layouts``        link / IPv4 / IPv6 / UDP and container header dtypes, declared once
``gathers``        header fields and payload rows gathered at many offsets (compiled or NumPy)
``datagram``       link/IP/UDP checks of a whole chunk, and the per-record general path
``trains``         whole IPv4 fragment trains reassembled with array operations
``reassembly``     :class:`Reassembler`: bounded IPv4/IPv6 fragment reassembly, record by record
``batching``       chunks to same-stream batches (filters, ordinals, grouping)
``bags``           :class:`BagReader`: MCAP files and ROS 1 / rosbag2 bags
``rosbag``         ROS 1 / rosbag2 through rosbags: cleanup after damage, old metadata.yaml completed
``mcap_records``   plain MCAP files record by record, chunks inflated within bounds
``rosmsgs``        the ROS message definitions lidarpkt reads and writes, and their type stores
``osf``            OSF files of decoded frames: format, field codecs, reader of the stored fields
``segments``       :func:`plan_segments` and the ownership rule of ``lidarpkt.open(segment=...)``
``udp``            :class:`UdpSource`: live UDP reception (``record``, ``view``, ``udp://`` sources)
=================  ===========================================================================
"""

from __future__ import annotations

from lidarpkt.core.lazy import lazy_names
from .magic import container_kind
from .protocol import PacketSource, open_packet_source

__all__ = ["PacketSource", "open_packet_source", "container_kind", "Segment", "plan_segments",
           "DEFAULT_SEGMENT_BYTES"]

# the segments' names on first use (lidarpkt/core/lazy.py): reading a capture whole does not need them
__getattr__, __dir__ = lazy_names(__name__, {"Segment": "segments", "plan_segments": "segments",
                                             "DEFAULT_SEGMENT_BYTES": "segments"}, __all__)
