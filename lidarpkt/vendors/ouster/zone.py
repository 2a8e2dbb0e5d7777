"""Ouster zone-monitoring packets (firmware 3.2+, sent to ``udp_port_zm``): the state of 16 zones.

Layout (:data:`~lidarpkt.vendors.ouster.auxiliary.ZONE_PACKET_DTYPE`): the lidar packet header, a timestamp
(ns, the sensor's clock), the SHA-256 of the live zone set, 16 zone states of 36 bytes
(:data:`~lidarpkt.vendors.ouster.auxiliary.ZONE_STATE_FIELDS`: live, id, error flags, trigger type and
status, triggered frames, point counts, min/max/mean range in mm), the footer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarpkt.core.packet import payload_rows
from .profiles import HEADER_TYPES
from .auxiliary import ZONE_PACKET_DTYPE, ZONE_PACKET_SIZE, ZONE_STATE_FIELDS
from .bitfield import read_bits

#: The zone-state fields, reserved bits left out.
ZONE_FIELD_NAMES = tuple(f.name for f in ZONE_STATE_FIELDS if not f.reserved)


@dataclass(eq=False)
class OusterZoneStates:
    """The zone states of N zone-monitoring packets.

    Attributes:
        header: packet-header fields by the manual's names (``packet_type``, ``frame_id``, ``init_id``,
            ``prod_sn``, ``alert_flags`` ...), each ``[N]``.
        timestamp_ns: ``uint64[N]`` the packet's timestamp (sensor clock).
        live_zoneset_hash: ``uint8[N, 32]`` SHA-256 of the zone set in force.
        zones: ``[N, 16]`` arrays by field name (:data:`ZONE_FIELD_NAMES`: ``live``, ``id``,
            ``error_flags``, ``trigger_type``, ``trigger_status``, ``triggered_frames``, ``count``,
            ``occlusion_count``, ``invalid_count``, ``max_count``, ``min_range_mm``, ``max_range_mm``,
            ``mean_range_mm``).
    """

    header: dict[str, np.ndarray]
    timestamp_ns: np.ndarray
    live_zoneset_hash: np.ndarray
    zones: dict[str, np.ndarray]

    def __len__(self) -> int:
        return int(self.timestamp_ns.shape[0])

    def records(self) -> list[dict]:
        """One JSON-ready dict per packet: its timestamp, zone-set hash and the 16 zone states."""
        out = []
        for i in range(len(self)):
            zones = [{k: int(v[i, z]) for k, v in self.zones.items()} for z in range(self.zones["id"].shape[1])]
            out.append({"timestamp_ns": int(self.timestamp_ns[i]), "frame_id": int(self.header["frame_id"][i]),
                        "live_zoneset_hash": self.live_zoneset_hash[i].tobytes().hex(), "zones": zones})
        return out


def decode_zone_packets(payload: np.ndarray, header_type: str = "STANDARD") -> OusterZoneStates:
    """Zone-monitoring packets ``uint8[N, 680]`` (or one packet, or bytes) → :class:`OusterZoneStates`.

    Raises:
        PacketFormatError: the packets are not 680 bytes, or not a ``uint8`` array.
    """
    arr = payload_rows(payload, ZONE_PACKET_SIZE, "Ouster zone-monitoring packets")
    pk = np.ascontiguousarray(arr).view(ZONE_PACKET_DTYPE)[:, 0]
    header = {f.name: read_bits(pk["header"], f) for f in HEADER_TYPES[header_type] if not f.reserved}
    zones = {f.name: read_bits(pk["zones"], f) for f in ZONE_STATE_FIELDS if not f.reserved}
    return OusterZoneStates(header, pk["timestamp_ns"].copy(), pk["live_zoneset_hash"].copy(), zones)
