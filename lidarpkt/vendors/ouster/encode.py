"""Encoding Ouster lidar packets from their fields: the exact inverse of :func:`decode_packets`.

Used for synthetic fixtures and round-trip tests. Fields absent from the input (reserved bits,
a missing pixel field, the footer) are written as zeros; the CRC-64/XZ is computed when the
firmware writes one.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.errors import PacketFormatError
from .crc import crc64_xz
from .decode import OusterPacketFields
from .fieldplan import plane_attr
from .profiles import HEADER_STATUS_FIELDS, Profile
from .bitfield import _to_raw, write_bits


def encode_packets(fields: OusterPacketFields, metadata=None, *, crc: bool | None = None) -> np.ndarray:
    """Packets (``uint8[N, packet_size]``) holding ``fields``.

    Args:
        fields: as :func:`decode_packets` returns them (any subset of pixel and header fields;
            missing ones are zero). Pixel values are in field units (mm for RANGE): values that
            are not a multiple of the wire unit, or too wide, raise.
        metadata: the sensor's metadata; decides whether a CRC is written (default: fields' own
            profile with no CRC).
        crc: write the CRC-64/XZ into the last 8 footer bytes; default when
            ``metadata.footer_kind == "crc"``. ``False`` copies the footer as given.

    Raises:
        PacketFormatError: a value does not fit its field, or array shapes disagree.
    """
    profile: Profile = fields.profile
    h, c = fields.pixels_per_column, fields.columns_per_packet
    n = len(fields)
    dtype = profile.packet_dtype(h, c)
    out = np.zeros((n, dtype.itemsize), np.uint8)
    pk = out.view(dtype)[:, 0]
    cols = pk["columns"]

    def put(name: str, value: np.ndarray | None, wire_max: int) -> None:
        if value is None:
            return
        value = np.asarray(value)
        if value.shape != (n, c):
            raise PacketFormatError(f"column field {name} must have shape {(n, c)}, got {value.shape}")
        if value.size and (value.min() < 0 or int(value.max()) > wire_max):
            raise PacketFormatError(f"column field {name} out of range 0..{wire_max}")
        cols[name] = value

    put("timestamp_ns", fields.timestamp_ns, 2**64 - 1)
    put("measurement_id", fields.measurement_id, 0xFFFF)
    put("status", fields.status, 0xFFFFFFFF if profile.legacy else 0xFFFF)
    if profile.legacy:
        put("frame_id", fields.column_frame_id, 0xFFFF)
        put("encoder_count", fields.encoder_count, 0xFFFFFFFF)
    else:
        header = pk["header"]
        for f in profile.header_fields:
            if f.name in fields.header:
                write_bits(header, f, _column(fields.header[f.name], (n,), f.name))

    words = np.zeros((n, c, h, profile.pixel_bytes // 4), np.uint32)
    for f in profile.pixel_fields:
        if f.name not in fields.pixels:
            continue
        raw = _to_raw(_column(fields.pixels[f.name], (n, c, h), f.name), f)
        k, off = divmod(f.start_bit, 32)
        words[..., k] |= raw.astype(np.uint32) << np.uint32(off)
    cols["pixels"] = words

    if profile.footer_bytes:
        footer = np.asarray(fields.footer)
        if footer.size:
            if footer.shape != (n, profile.footer_bytes):
                raise PacketFormatError(f"footer must have shape {(n, profile.footer_bytes)}, got {footer.shape}")
            pk["footer"] = footer
        if crc is None:
            crc = metadata is not None and metadata.footer_kind == "crc"
        if crc:
            out[:, -8:] = crc64_xz(out[:, :-8]).astype("<u8").view(np.uint8).reshape(n, 8)
    return out


def _column(value, shape: tuple[int, ...], name: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.shape != shape:
        raise PacketFormatError(f"field {name} must have shape {shape}, got {arr.shape}")
    if arr.size and arr.min() < 0:
        raise PacketFormatError(f"field {name} must not be negative")
    return arr


def empty_fields(metadata, n: int) -> OusterPacketFields:
    """Zeroed fields for ``n`` packets of ``metadata``'s profile (a start for synthetic packets):
    every pixel field of the profile (``[N, C, H]``), the column fields (``[N, C]``), the header
    fields ``frame_id``/``init_id``/``prod_sn`` set from the metadata, and a zero footer."""
    profile: Profile = metadata.profile
    h, c = metadata.pixels_per_column, metadata.columns_per_packet
    pixels = {f.name: np.zeros((n, c, h), f.dtype) for f in profile.pixel_fields if not f.reserved}
    header: dict[str, np.ndarray] = {}
    if not profile.legacy:
        header["packet_type"] = np.ones(n, np.uint16)  # 0x1 = lidar data packet
        header["frame_id"] = np.zeros(n, np.uint32)
        header["init_id"] = np.full(n, metadata.init_id, np.uint32)
        header["prod_sn"] = np.full(n, metadata.serial_int or 0, np.uint64)
    return OusterPacketFields(
        profile=profile,
        pixels_per_column=h,
        columns_per_packet=c,
        header=header,
        timestamp_ns=np.zeros((n, c), np.uint64),
        measurement_id=np.zeros((n, c), np.uint16),
        status=np.zeros((n, c), np.uint32),
        pixels=pixels,
        footer=np.zeros((n, profile.footer_bytes), np.uint8),
        column_frame_id=np.zeros((n, c), np.uint16) if profile.legacy else None,
        encoder_count=np.zeros((n, c), np.uint32) if profile.legacy else None,
    )


_FRAME_SLOTS = (
    ("RANGE", "REFLECTIVITY", "SIGNAL", "FLAGS"),
    ("RANGE2", "REFLECTIVITY2", "SIGNAL2", "FLAGS2"),
)
ENCODER_COUNTS_PER_TURN = 90112  # LEGACY encoder ticks per revolution


def frame_fields(frame, metadata, *, all_packets: bool = False, init_id: int | None = None) -> OusterPacketFields:
    """The packet fields that carry ``frame`` (a :class:`~lidarpkt.core.frame.Frame` of this sensor's layout).

    One packet per ``columns_per_packet`` columns inside ``column_window``; by default only
    packets with at least one valid column (``all_packets`` emits the whole window). Column
    measurement ids are the column indices; missing per-column values take the sensor's
    defaults: status valid (``0xFFFFFFFF`` LEGACY, ``0x1`` otherwise) for valid columns,
    LEGACY encoder count ``90112 · c / W``. The header gets the frame id, the metadata's (or
    ``init_id``'s) init_id and the serial; the footer is zero (the CRC is added by
    :func:`encode_packets` when the firmware writes one).

    Raises:
        PacketFormatError: the frame's shape or return slots do not match the metadata.
    """
    profile: Profile = metadata.profile
    h, w, c = metadata.pixels_per_column, metadata.columns_per_frame, metadata.columns_per_packet
    r = profile.returns
    if frame.range_mm.shape != (r, h, w):
        raise PacketFormatError(
            f"frame shape {frame.range_mm.shape} does not match the metadata: {r} returns × {h} rows × {w} columns"
        )
    window_packets = np.unique(np.flatnonzero(metadata.window_mask) // c)
    if not all_packets:
        valid = np.asarray(np.asarray(frame.column_valid, bool).reshape(-1, c).any(axis=1))  # bool[packets]
        window_packets = window_packets[valid[window_packets]]
    n = len(window_packets)
    cols = (window_packets[:, None] * c + np.arange(c)[None, :])  # [n, C] column indices

    def per_column(arr, default):
        return np.asarray(arr)[cols] if arr is not None else np.broadcast_to(default, cols.shape)

    def per_pixel(arr):  # [H, W] → [n, C, H]
        return np.asarray(arr)[:, cols].transpose(1, 2, 0)

    valid_cols = np.asarray(frame.column_valid, bool)[cols]
    pixels: dict[str, np.ndarray] = {}
    attrs = ("range_mm", "reflectivity", "signal", "flags")
    names = set(profile.field_names)
    for slot in range(r):
        for attr, name in zip(attrs, _FRAME_SLOTS[slot]):
            arr = getattr(frame, attr)
            if name in names and arr is not None:
                pixels[name] = per_pixel(arr[slot])
    if "NEAR_IR" in names and frame.near_ir is not None:
        pixels["NEAR_IR"] = per_pixel(frame.near_ir)
    for name in names - {n for sl in _FRAME_SLOTS for n in sl} - {"NEAR_IR"}:  # WINDOW, ZONE_MASK, R, G, B
        if plane_attr(name) in frame.extra:
            pixels[name] = per_pixel(frame.extra[plane_attr(name)])

    valid_status = 0xFFFFFFFF if profile.legacy else 1
    status = per_column(frame.status, 0).astype(np.uint32)
    status = np.where((status == 0) & valid_cols, np.uint32(valid_status), status)
    header: dict[str, np.ndarray] = {}
    column_frame_id = encoder_count = None
    if profile.legacy:
        column_frame_id = np.full(cols.shape, frame.frame_id & 0xFFFF, np.uint16)
        default_enc = (ENCODER_COUNTS_PER_TURN * cols) // w
        encoder_count = per_column(frame.encoder_count, 0).astype(np.uint32)
        encoder_count = np.where(encoder_count == 0, default_enc, encoder_count).astype(np.uint32)
    else:
        header = {
            "packet_type": np.ones(n, np.uint16),
            "frame_id": np.full(n, frame.frame_id, np.uint64),
            "init_id": np.full(n, metadata.init_id if init_id is None else init_id, np.uint32),
            "prod_sn": np.full(n, metadata.serial_int or 0, np.uint64),
        }
        for key in HEADER_STATUS_FIELDS:  # per column in the frame: the packet's first column's
            if key in frame.extra:
                header[key] = np.asarray(frame.extra[key])[cols[:, 0]]
    return OusterPacketFields(
        profile=profile,
        pixels_per_column=h,
        columns_per_packet=c,
        header=header,
        timestamp_ns=per_column(frame.column_timestamp_ns, 0).astype(np.uint64),
        measurement_id=cols.astype(np.uint16),
        status=status,
        pixels=pixels,
        footer=np.zeros((n, profile.footer_bytes), np.uint8),
        column_frame_id=column_frame_id,
        encoder_count=encoder_count,
    )


def encode_frame(frame, metadata, **options) -> np.ndarray:
    """``frame`` as lidar packets ``uint8[n, packet_size]`` in column order (see :func:`frame_fields`)."""
    return encode_packets(frame_fields(frame, metadata, **options), metadata)
