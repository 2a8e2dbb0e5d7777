"""Is a stream a VLP-16? Data or position packets? What does it say about itself?

Data packets: 1206 bytes, every block flag 0xEEFF, azimuths below 36000, a known return
mode. The product byte says 0x22 on VLP-16s, but early (2014) units say 0x21, which is
officially the HDL-32E (same packet layout). They are told apart by timing: a VLP-16 sends
a packet every 12 × 110.592 = 1327.1 µs in single-return modes (663.6 µs in dual), an
HDL-32E every 12 × 46.08 = 553 µs. A one-packet 0x21 batch has no timing; then the layout
decides: on a VLP-16, channels j and j + 16 of a block are the same laser one firing
sequence apart and nearly always see the same distance, while on an HDL-32E they are
different lasers.

Position packets: 512 bytes with bytes 0–186 zero (the HDL-32E writes gyroscope,
temperature and accelerometer readings there).
"""

from __future__ import annotations

import numpy as np

from ..packet import PacketBatch
from .clock import hour_steps_us
from .decode import decode_packets, decode_position_packets
from .models import HDL32E_PACKET_PERIOD_US, PRODUCT_NAMES, VLP16
from .nmea import parse_nmea
from .packet import DATA_PACKET_SIZE, POSITION_PACKET_SIZE, PPS_STATUS, PRODUCT_HDL32E, PRODUCT_VLP16, RETURN_MODES
from .stream import stream_kind
from .timing import rotation_frequency_hz


def _forward_steps_us(timestamp_us: np.ndarray) -> np.ndarray:
    """Steps between consecutive packet stamps that go forward by less than 0.1 s (across the hour)."""
    d = hour_steps_us(timestamp_us)[1:]
    return d[(d > 0) & (d < 100_000)]


def _median_period_us(timestamp_us: np.ndarray) -> float | None:
    d = _forward_steps_us(timestamp_us)
    return float(np.median(d)) if d.size else None


def _layout_says_vlp16(raw) -> bool:
    """Channels j and j+16 agree (same laser, next sequence) far more often than on an HDL-32E.

    Too few returns to tell (a sensor facing the sky): the azimuth step between distinct blocks
    decides. At the usual 600 RPM a VLP-16 block spans 0.4° (two 55.296 µs sequences), an HDL-32E
    block 0.17° (46.08 µs); 0.27° separates them for any rate between 500 and 720 RPM.
    """
    a = raw.distance_2mm[:, :, :VLP16.lasers].astype(np.int32)
    b = raw.distance_2mm[:, :, VLP16.lasers:].astype(np.int32)
    both = (a > 0) & (b > 0)
    if np.count_nonzero(both) < 16:
        steps = np.diff(raw.azimuth_cdeg.astype(np.int32), axis=1) % 36000
        steps = steps[steps > 0]  # dual-mode pairs repeat their azimuth
        return bool(steps.size) and float(np.median(steps)) >= 27
    close = np.abs(a - b) <= np.maximum(25, (a + b) // 40)  # within 50 mm or 5 %
    return bool(np.count_nonzero(close & both) / np.count_nonzero(both) > 0.6)


def data_kind(batch: PacketBatch) -> str | None:
    """``"vlp16"``, ``"hdl32e"``, ``"other"`` (another Velodyne model by its product byte: Puck Hi-Res,
    VLP-32C, ...) or ``None`` (not Velodyne-like data packets) for a batch of 1206-byte payloads."""
    if batch.payload_size != DATA_PACKET_SIZE or len(batch) == 0:
        return None
    raw = decode_packets(batch.payload, copy=False)
    ok = raw.flag_ok & np.isin(raw.return_mode, list(RETURN_MODES))
    if np.count_nonzero(ok) * 2 <= len(raw):  # mostly not VLP-16 layout
        return None
    product = int(np.bincount(raw.product_id[ok]).argmax())
    if product == PRODUCT_VLP16:
        return "vlp16"
    if product != PRODUCT_HDL32E:
        return "other" if product in PRODUCT_NAMES else None
    raw = raw.select(ok)
    dual = bool(np.median(raw.return_mode) == 0x39)
    expected = VLP16.packet_period_us("dual" if dual else "strongest")
    hdl = HDL32E_PACKET_PERIOD_US / 2 if dual else HDL32E_PACKET_PERIOD_US
    period = _median_period_us(raw.timestamp_us)
    if period is not None:
        if abs(period - expected) < 0.05 * expected:
            return "vlp16"
        if abs(period - hdl) < 0.05 * hdl:
            return "hdl32e"
        # neither: lost packets stretch the steps; count steps that are whole VLP-16 periods
        d = _forward_steps_us(raw.timestamp_us)
        fits = lambda p: np.abs(d - np.rint(d / p) * p) <= 3  # noqa: E731 - µs stamps jitter by 1
        n_vlp, n_hdl = int(np.count_nonzero(fits(expected))), int(np.count_nonzero(fits(hdl)))
        if n_vlp != n_hdl:
            return "vlp16" if n_vlp > n_hdl else "hdl32e"
    return "vlp16" if _layout_says_vlp16(raw) else "hdl32e"


def position_kind(batch: PacketBatch) -> str | None:
    """``"vlp16"``, ``"hdl32e"`` or ``None`` for a batch of 512-byte payloads."""
    if batch.payload_size != POSITION_PACKET_SIZE or len(batch) == 0:
        return None
    pos = decode_position_packets(batch.payload)
    if np.any(pos.pps_status > 3):
        return None
    head_zero = ~np.any(pos.unused_head[:, :187], axis=1)
    return "vlp16" if head_zero.mean() > 0.5 else "hdl32e"


def classify(batch: PacketBatch) -> str | None:
    """``"data"`` or ``"position"`` for VLP-16 packet streams, ``None`` for anything else (an HDL-32E too).

    The size says which stream it could be (:func:`lidarpkt.velodyne.stream.stream_kind`, the recorder's
    cheap test); the content decides."""
    kind = stream_kind(batch.payload_size)
    if kind == "data":
        return "data" if data_kind(batch) == "vlp16" else None
    if kind == "position":
        return "position" if position_kind(batch) == "vlp16" else None
    return None


def describe_stream(batch: PacketBatch) -> dict | None:
    """A JSON-ready description of a Velodyne stream for ``lidarpkt info``, ``None`` if it is none.

    Data: ``{"kind": "VLP-16 data", "return_mode": "strongest", "product_id": 0x22,
    "product_name": ..., "packets": N, "packet_period_us": ..., "rotation_hz": ...,
    "malformed_packets": ..., "first_timestamp_us": ...}``; an HDL-32E gives
    ``{"kind": "HDL-32E data (not a VLP-16)", ...}``.
    Position: ``{"kind": "VLP-16 position", "pps_status": "locked", "nmea_first": "$GPRMC,…",
    "gps_time_first": "2014-11-04T…Z" | None, "fix_valid": bool | None, ...}``.
    """
    if batch.payload_size == DATA_PACKET_SIZE:
        kind = data_kind(batch)
        if kind is None:
            return None
        raw = decode_packets(batch.payload)
        ok = raw.flag_ok & np.isin(raw.return_mode, list(RETURN_MODES))
        good = raw.select(ok)
        product = int(np.bincount(good.product_id).argmax())
        modes = sorted({RETURN_MODES[int(m)] for m in np.unique(good.return_mode)})
        out = {
            "kind": "VLP-16 data" if kind == "vlp16" else
                    f"{'HDL-32E' if kind == 'hdl32e' else PRODUCT_NAMES[product]} data (not a VLP-16)",
            "return_mode": modes[0] if len(modes) == 1 else modes,
            "product_id": product,
            "product_name": PRODUCT_NAMES.get(product, f"unknown 0x{product:02x}"),
            "packets": len(batch),
            "malformed_packets": int(np.count_nonzero(~ok)),
            "packet_period_us": _median_period_us(good.timestamp_us),
            "first_timestamp_us": int(good.timestamp_us[0]) if len(good) else None,
        }
        if kind == "vlp16":
            out["rotation_hz"] = rotation_frequency_hz(good.azimuth_cdeg, good.return_mode == 0x39) if len(good) else None
            if product == PRODUCT_HDL32E:
                out["note"] = "an early VLP-16 by its packet timing and layout"  # the product byte is shown beside it
        return out
    if batch.payload_size == POSITION_PACKET_SIZE:
        kind = position_kind(batch)
        if kind is None:
            return None
        pos = decode_position_packets(batch.payload)
        sentences = pos.sentences()
        first = next((s for s in sentences if s), "")
        fix_valid: bool | str | None = None  # str: why the sentence is unreadable
        gps_time = None
        if first:
            try:
                fix = parse_nmea(first)
                fix_valid = fix.valid
                if fix.utc_ns is not None:
                    import datetime as _dt

                    gps_time = _dt.datetime.fromtimestamp(fix.utc_ns / 1e9, _dt.timezone.utc).isoformat().replace("+00:00", "Z")
            except Exception as exc:  # NMEAError: reported, not raised, in a description
                fix_valid = f"unreadable: {exc}"
        return {
            "kind": "VLP-16 position" if kind == "vlp16" else "HDL-32E position (not a VLP-16)",
            "packets": len(batch),
            "pps_status": PPS_STATUS.get(int(pos.pps_status[0]), int(pos.pps_status[0])),
            "nmea_first": first or None,
            "gps_time_first": gps_time,
            "fix_valid": fix_valid,
            "first_timestamp_us": int(pos.timestamp_us[0]),
        }
    return None
