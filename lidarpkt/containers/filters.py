"""The keyword options (packet filters first) each packet reader takes, and the one error for the
others. Shared by :func:`lidarpkt.containers.protocol.open_packet_source` and the readers themselves,
so that a reader made directly refuses the same options in the same words."""

from __future__ import annotations

import os
from typing import Any

from ..errors import UnsupportedFilterError

# keyword options each reader takes (filters first); None always means "no filter"
PCAP_OPTIONS = frozenset({"ports", "src_addresses", "payload_sizes", "batch_packets", "reassembly_timeout_ns",
                          "max_pending_datagrams", "max_pending_bytes", "segment"})
BAG_OPTIONS = frozenset({"topics", "payload_sizes"})


def check_filters(path: str | os.PathLike[str], kind: str, options: dict[str, Any]) -> None:
    """Raise :class:`UnsupportedFilterError` for an option (not ``None``) that a ``kind`` reader
    (``"pcap"``, else a bag or MCAP) does not know or cannot apply."""
    allowed = PCAP_OPTIONS if kind == "pcap" else BAG_OPTIONS
    unknown = sorted(k for k, v in options.items() if v is not None and k not in allowed)
    if not unknown:
        return
    names = ", ".join(f"{n}=" for n in unknown)
    if kind != "pcap" and set(unknown) <= {"ports", "src_addresses"}:
        raise UnsupportedFilterError(f"{path}: {names} cannot filter a {kind} file: it records no UDP ports or "
                                     "addresses; choose packets by topics=... or payload_sizes=...")
    raise UnsupportedFilterError(f"{path}: unknown packet filter {names}; a {kind} reader takes "
                                 f"{', '.join(sorted(allowed))}")
