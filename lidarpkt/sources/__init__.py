"""The packet-source layer: container walkers, link/IP/UDP parsing, batching, and segments of a capture.

Public here: :class:`~lidarpkt.sources.segments.Segment` and :func:`~lidarpkt.sources.segments.plan_segments`.
"""

from __future__ import annotations

from .segments import DEFAULT_SEGMENT_BYTES, Segment, plan_segments

__all__ = ["Segment", "plan_segments", "DEFAULT_SEGMENT_BYTES"]
