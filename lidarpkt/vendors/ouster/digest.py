"""ouster-sdk style digests (MD5 per field) of Ouster packets and frames.

The ``*_digest.json`` files published with ouster-sdk's test captures hold, per key, the MD5 of
the field values of every lidar packet (packet part) and of every frame (frame part). Here they
are computed from our own decode (fields derived from :mod:`lidarpkt.vendors.ouster.profiles`), so that
comparing them with the published files checks every bit of our decoding. See
``fixtures/external/SOURCES.md`` ("How the Ouster digest files are computed").
"""

from __future__ import annotations

import hashlib
from typing import Iterable

import numpy as np

from lidarpkt.errors import UsageError
from lidarpkt.core.frame import Frame
from .decode import OusterPacketFields, read_pixel_field
from .bitfield import BitField
from .profiles import Profile


def raw_word_fields(profile: Profile) -> tuple[BitField, ...]:
    """``RAW32_WORD1..k``: the pixel's 32-bit words, as ouster-sdk exposes them."""
    return tuple(BitField(f"RAW32_WORD{k + 1}", 32 * k, 32) for k in range(profile.pixel_bytes // 4))


class PacketDigest:
    """Incremental packet-part digest: feed decoded packet batches in capture order."""

    def __init__(self) -> None:
        self._md5: dict[str, "hashlib._Hash"] = {}

    def _feed(self, key: str, arr: np.ndarray) -> None:
        self._md5.setdefault(key, hashlib.md5()).update(np.ascontiguousarray(arr).tobytes())

    def update(self, fields: OusterPacketFields, raw_payload: np.ndarray | None = None) -> None:
        """Add N packets. ``raw_payload`` (``uint8[N, L]``) adds the ``RAW32_WORD*`` keys."""
        prof = fields.profile
        n, c = fields.timestamp_ns.shape
        self._feed("TIMESTAMP", fields.timestamp_ns.astype("<u8"))
        self._feed("MEASUREMENT_ID", fields.measurement_id.astype("<u2"))
        self._feed("STATUS", fields.status.astype("<u4"))
        if prof.legacy and fields.encoder_count is not None and fields.column_frame_id is not None:  # set for LEGACY
            self._feed("ENCODER_COUNT", fields.encoder_count.astype("<u4"))
            self._feed("FRAME_ID", fields.column_frame_id.astype("<u2"))
        else:  # the SDK does not fill these for non-legacy packets
            self._feed("ENCODER_COUNT", np.zeros((n, c), "<u4"))
            self._feed("FRAME_ID", np.zeros((n, c), "<u2"))
        for f in prof.pixel_fields:
            if not f.reserved:
                # per packet: (pixels_per_column, columns_per_packet), row-major
                self._feed(f.name, fields.pixels[f.name].transpose(0, 2, 1).astype(f.dtype.newbyteorder("<")))
        if raw_payload is not None:
            from .decode import packet_view

            words = packet_view(raw_payload, prof, fields.pixels_per_column, fields.columns_per_packet)["columns"]["pixels"]
            for f in raw_word_fields(prof):
                self._feed(f.name, read_pixel_field(words, f).transpose(0, 2, 1).astype("<u4"))

    def hexdigests(self) -> dict[str, str]:
        return {k: v.hexdigest() for k, v in self._md5.items()}


_FRAME_PIXEL_KEYS = (
    ("RANGE", "range_mm", 0, "<u4"),
    ("RANGE2", "range_mm", 1, "<u4"),
    ("SIGNAL", "signal", 0, "<u2"),
    ("SIGNAL2", "signal", 1, "<u2"),
    ("REFLECTIVITY", "reflectivity", 0, "u1"),
    ("REFLECTIVITY2", "reflectivity", 1, "u1"),
    ("FLAGS", "flags", 0, "u1"),
    ("FLAGS2", "flags", 1, "u1"),
)


def frame_digest(frame: Frame) -> dict[str, str]:
    """Frame-part digest of one frame (staggered ``H × W`` arrays, missing columns zero)."""

    def md5(arr: np.ndarray) -> str:
        return hashlib.md5(np.ascontiguousarray(arr).tobytes()).hexdigest()

    if frame.status is None or frame.measurement_id is None:
        raise UsageError(f"frame_digest(frame): a {frame.sensor.vendor} frame has no Ouster column status")
    out = {
        "FRAME_ID": str(frame.frame_id),
        "TIMESTAMP": md5(frame.column_timestamp_ns.astype("<u8")),
        "STATUS": md5(frame.status.astype("<u8")),
        "MEASUREMENT_ID": md5(frame.measurement_id.astype("<u2")),
        "ENCODER_COUNT": md5(
            (frame.encoder_count if frame.encoder_count is not None else np.zeros(frame.shape[2])).astype("<u8")
        ),
    }
    for key, attr, slot, dt in _FRAME_PIXEL_KEYS:
        arr = getattr(frame, attr)
        if arr is not None and arr.shape[0] > slot:
            out[key] = md5(arr[slot].astype(dt))
    if frame.near_ir is not None:
        out["NEAR_IR"] = md5(frame.near_ir.astype("<u2"))
    if "window" in frame.extra:
        out["WINDOW"] = md5(frame.extra["window"].astype("u1"))
    return out


def compare_digest(expected: dict, packet_hash: dict[str, str], frames: Iterable[Frame]) -> list[str]:
    """Differences between a published digest document and ours, as ouster-sdk compares them:
    every key of the stored document must be equal, except ``ENCODER_COUNT`` (deprecated).
    Returns a list of human-readable mismatches (empty when all match)."""
    problems = []
    for key, value in expected.get("packet_hash", {}).items():
        if key == "ENCODER_COUNT":
            continue
        if packet_hash.get(key) != value:
            problems.append(f"packet {key}: expected {value}, got {packet_hash.get(key)}")
    stored_frames = expected.get("scans", expected.get("frames", []))
    ours = [frame_digest(f) for f in frames]
    if len(ours) != len(stored_frames):
        problems.append(f"{len(stored_frames)} frames expected, got {len(ours)}")
    for i, (want, got) in enumerate(zip(stored_frames, ours)):
        for key, value in want.items():
            if key == "ENCODER_COUNT":
                continue
            if got.get(key) != value:
                problems.append(f"frame {i} {key}: expected {value}, got {got.get(key)}")
    return problems
