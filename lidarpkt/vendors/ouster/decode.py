"""Batch decoding of Ouster lidar packets into their raw fields, all packets in one NumPy pass.

A batch is ``uint8[N, packet_size]``; it is viewed through the profile's structured dtype
(no copy), column-header fields are dtype fields, and each pixel field is one shift and mask
on a 32-bit word column of all N × C × H pixels (see :mod:`lidarpkt.vendors.ouster.profiles`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidarpkt.errors import PacketFormatError, SensorMismatchError
from .crc import footer_crc_ok
from .profiles import LEGACY_STATUS_VALID, Profile
from .bitfield import BitField, read_bits


@dataclass(eq=False)
class OusterPacketFields:
    """The raw fields of N lidar packets of one profile, in the manual's units.

    Attributes:
        profile: the packets' :class:`Profile`; pixels_per_column: H; columns_per_packet: C.
        header: packet-header fields by the manual's names (``packet_type``, ``frame_id``,
            ``init_id``, ``prod_sn``, ``alert_flags``, ``countdown_thermal_shutdown``,
            ``countdown_shot_limiting``, ``thermal_shutdown``, ``shot_limiting``, and the
            ``_reserved_<bit>`` leftovers), each ``[N]``; empty for LEGACY.
        timestamp_ns: ``uint64[N, C]`` column timestamps (sensor clock, ns).
        measurement_id: ``uint16[N, C]``.
        status: ``uint32[N, C]``: LEGACY status word (0xFFFFFFFF = valid) or the non-legacy
            16-bit column status (bit 0 = valid) zero-extended.
        column_frame_id: LEGACY ``uint16[N, C]`` frame id of each column, else ``None``.
        encoder_count: LEGACY ``uint32[N, C]`` (90112 counts per turn), else ``None``.
        pixels: ``[N, C, H]`` arrays by field name (``RANGE`` in mm, up-shifts applied; reserved
            bit ranges under ``_reserved_<bit>``).
        footer: ``uint8[N, 32]`` packet footer (``uint8[N, 0]`` for LEGACY).
        crc_ok: ``bool[N]`` CRC-64/XZ check of the footer when it was verified, else ``None``.
    """

    profile: Profile
    pixels_per_column: int
    columns_per_packet: int
    header: dict[str, np.ndarray]
    timestamp_ns: np.ndarray
    measurement_id: np.ndarray
    status: np.ndarray
    pixels: dict[str, np.ndarray]
    footer: np.ndarray
    column_frame_id: np.ndarray | None = None
    encoder_count: np.ndarray | None = None
    crc_ok: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.timestamp_ns.shape[0])

    @property
    def frame_id(self) -> np.ndarray:
        """``int64[N]`` frame id of each packet: header field, or the first column's for LEGACY."""
        if self.profile.legacy and self.column_frame_id is not None:  # set for LEGACY
            return self.column_frame_id[:, 0].astype(np.int64)
        return self.header["frame_id"].astype(np.int64)

    @property
    def init_id(self) -> np.ndarray | None:
        return None if self.profile.legacy else self.header["init_id"]

    @property
    def prod_sn(self) -> np.ndarray | None:
        return None if self.profile.legacy else self.header["prod_sn"]

    @property
    def column_valid(self) -> np.ndarray:
        """``bool[N, C]``: the column's status says valid."""
        if self.profile.legacy:
            return self.status == LEGACY_STATUS_VALID
        return (self.status & 1).astype(bool)

    def select(self, rows: np.ndarray | slice) -> "OusterPacketFields":
        """The fields of the chosen packets (mask, indices or a slice)."""

        def pick(a):
            return None if a is None else a[rows]

        return OusterPacketFields(
            self.profile,
            self.pixels_per_column,
            self.columns_per_packet,
            {k: v[rows] for k, v in self.header.items()},
            self.timestamp_ns[rows],
            self.measurement_id[rows],
            self.status[rows],
            {k: v[rows] for k, v in self.pixels.items()},
            self.footer[rows],
            pick(self.column_frame_id),
            pick(self.encoder_count),
            pick(self.crc_ok),
            {k: v[rows] for k, v in self.extra.items()},
        )


def _as_rows(payload: np.ndarray) -> np.ndarray:
    payload = np.asarray(payload)
    return payload[None, :] if payload.ndim == 1 else payload


def packet_view(payload: np.ndarray, profile: Profile, pixels_per_column: int, columns_per_packet: int) -> np.ndarray:
    """``payload`` (``uint8[N, L]``) as a structured array ``[N]`` of the profile's packet dtype (no copy).

    Raises :class:`SensorMismatchError` when ``L`` is not the profile's packet size.
    """
    dtype = profile.packet_dtype(pixels_per_column, columns_per_packet)
    payload = _as_rows(payload)
    if payload.dtype != np.uint8 or payload.ndim != 2:
        raise PacketFormatError(f"Ouster payloads must be a uint8[N, L] array, got {payload.dtype}{list(payload.shape)}")
    if payload.shape[1] != dtype.itemsize:
        raise SensorMismatchError(
            f"{payload.shape[1]}-byte packets do not match the metadata: profile {profile.name} with "
            f"{pixels_per_column} pixels × {columns_per_packet} columns makes {dtype.itemsize}-byte packets "
            "(wrong metadata file for this capture?)"
        )
    if payload.strides[1] != 1:
        payload = np.ascontiguousarray(payload)
    # rows need only be contiguous each (a strided view of packets in a capture file is no copy)
    return payload.view(dtype)[:, 0]


def read_pixel_field(words: np.ndarray, f: BitField, out: np.ndarray | None = None) -> np.ndarray:
    """Field ``f`` from pixel words ``<u4[..., pixel_bytes // 4]`` → ``[...]`` in ``f.dtype``, up-shift applied.

    ``out`` (``f.dtype``, the shape of ``words[..., 0]``) receives the values when given.
    """
    k, off = divmod(f.start_bit, 32)
    if off % 8 == 0 and f.width in (8, 16, 32) and not f.upshift and words.strides[-1] == 4:
        # byte-aligned field: a strided view of its bytes, one copy
        byte = 4 * k + off // 8
        src = words.view(np.uint8)[..., byte : byte + f.width // 8].view(f.dtype.newbyteorder("<"))[..., 0]
        if out is None:
            return src.astype(f.dtype)
        np.copyto(out, src, casting="unsafe")
        return out
    w = words[..., k]
    if out is None:
        out = np.empty(w.shape, f.dtype)
    # ufuncs write the narrow result directly (one pass each over the strided words)
    if off and off + f.width < 32:
        np.bitwise_and(np.right_shift(w, np.uint32(off)), np.uint32(f.mask), out=out, casting="unsafe")
    elif off:
        np.right_shift(w, np.uint32(off), out=out, casting="unsafe")
    elif f.width < 32:
        np.bitwise_and(w, np.uint32(f.mask), out=out, casting="unsafe")
    else:
        np.copyto(out, w, casting="unsafe")
    if f.upshift:
        np.left_shift(out, f.dtype.type(f.upshift), out=out)
    return out


def decode_packets(
    payload: np.ndarray,
    metadata,
    *,
    verify_crc: bool | None = None,
    fields: tuple[str, ...] | None = None,
    header_fields: tuple[str, ...] | None = None,
) -> OusterPacketFields:
    """Decode N lidar packets of one sensor.

    Args:
        payload: ``uint8[N, packet_size]`` (or one packet ``uint8[packet_size]``).
        metadata: the sensor's :class:`~lidarpkt.vendors.ouster.metadata.OusterMetadata`.
        verify_crc: check the CRC-64/XZ in the footer; default: when the firmware writes one
            (``metadata.footer_kind == "crc"``).
        fields: pixel fields to decode (default all, reserved bits included).
        header_fields: packet-header fields to decode (default all, reserved bits included).

    Returns:
        :class:`OusterPacketFields`.

    Raises:
        SensorMismatchError: the packet size is not the metadata's.
        PacketFormatError: ``payload`` is not a 2-D ``uint8`` array.
    """
    profile: Profile = metadata.profile
    h, c = metadata.pixels_per_column, metadata.columns_per_packet
    pk = packet_view(payload, profile, h, c)
    cols = pk["columns"]
    header: dict[str, np.ndarray] = {}
    if profile.header_fields:
        raw_header = pk["header"]
        for f in profile.header_fields:
            if header_fields is None or f.name in header_fields:
                header[f.name] = read_bits(raw_header, f)
    words = cols["pixels"]  # <u4[N, C, H, pixel_bytes // 4]
    pixels = {
        f.name: read_pixel_field(words, f) for f in profile.pixel_fields if fields is None or f.name in fields
    }
    status = cols["status"].astype(np.uint32)
    out = OusterPacketFields(
        profile=profile,
        pixels_per_column=h,
        columns_per_packet=c,
        header=header,
        timestamp_ns=cols["timestamp_ns"].copy(),
        measurement_id=cols["measurement_id"].copy(),
        status=status,
        pixels=pixels,
        footer=pk["footer"].copy(),
        column_frame_id=cols["frame_id"].copy() if profile.legacy else None,
        encoder_count=cols["encoder_count"].copy() if profile.legacy else None,
    )
    if verify_crc is None:
        verify_crc = metadata.footer_kind == "crc"
    if verify_crc and not profile.legacy:
        out.crc_ok = footer_crc_ok(_as_rows(payload))
    return out
