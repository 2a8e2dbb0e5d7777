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

from lidarpkt.errors import UnknownSensorError
from lidarpkt.core.median import median
from lidarpkt.core.packet import PacketBatch
from .clock import hour_steps_us
from .decode import decode_packets, decode_position_packets
from .models import (AMBIGUOUS_PRODUCTS, BANK_FLAGS, HDL32E, HDL32E_PACKET_PERIOD_US, HDL64E_S2, HDL64E_S3, MODELS,
                     PRODUCT_NAMES, VLP16, VelodyneModel, model_for_product)
from .packet import (DATA_PACKET_SIZE, POSITION_PACKET_SIZE, PPS_STATUS, PRODUCT_HDL32E, PRODUCT_VLP16, RETURN_MODES,
                     known_return_mode)
from .stream import stream_kind
from .timing import rotation_frequency_hz


def _forward_steps_us(timestamp_us: np.ndarray) -> np.ndarray:
    """Steps between consecutive packet stamps that go forward by less than 0.1 s (across the hour)."""
    d = hour_steps_us(timestamp_us)[1:]
    return d[(d > 0) & (d < 100_000)]


def _median_period_us(timestamp_us: np.ndarray) -> float | None:
    d = _forward_steps_us(timestamp_us)
    return median(d) if d.size else None


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
        return bool(steps.size) and median(steps) >= 27
    close = np.abs(a - b) <= np.maximum(25, (a + b) // 40)  # within 50 mm or 5 %
    return bool(np.count_nonzero(close & both) / np.count_nonzero(both) > 0.6)


_IS_BANK_FLAG = np.zeros(1 << 16, bool)  # flag word -> is it one of BANK_FLAGS: one lookup, where np.isin sorts
_IS_BANK_FLAG[list(BANK_FLAGS)] = True


def _velodyne_shaped(raw) -> np.ndarray:
    """``bool[N]``: block 0 flagged 0xEEFF, blocks 0–7 flagged with a bank (0xEEFF … 0xBBFF; the VLS-128's
    dual packets leave blocks 8–11 unused), block 0's azimuth below 360°: a Velodyne data packet of some model."""
    flags = np.asarray(raw.flag)
    ok = (flags[:, 0] == BANK_FLAGS[0]) & (np.asarray(raw.azimuth_cdeg)[:, 0] <= 36000)
    for b in range(1, min(8, flags.shape[1])):  # block by block (see decode.blocks_ok)
        ok &= _IS_BANK_FLAG[flags[:, b]]
    return ok


def data_kind(batch: PacketBatch) -> str | None:
    """``"vlp16"``, ``"hdl32e"``, ``"other"`` (another Velodyne model: by its factory byte, the HDL-64E by its
    upper/lower blocks, or an unknown byte the decoder will name) or ``None`` (not Velodyne data packets)
    for a batch of 1206-byte payloads."""
    if batch.payload_size != DATA_PACKET_SIZE or len(batch) == 0:
        return None
    raw = decode_packets(batch.payload, copy=False)
    shaped = _velodyne_shaped(raw)
    hdl64 = _is_hdl64e(raw)
    ok = shaped & (known_return_mode(raw.return_mode) | hdl64)
    if np.count_nonzero(ok) * 2 <= len(raw):  # mostly not Velodyne layout
        return None
    if np.count_nonzero(hdl64 & ok) * 2 > np.count_nonzero(ok):
        return "other"
    product = int(np.bincount(raw.product_id[ok]).argmax())
    if product == PRODUCT_VLP16:
        return "vlp16"
    if product != PRODUCT_HDL32E:
        return "other"
    return "vlp16" if _timing_or_layout_says_vlp16(raw.select(ok)) else "hdl32e"


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
    """``"data"`` or ``"position"`` for Velodyne packet streams (any model), ``None`` for anything else.

    The size says which stream it could be (:func:`lidarpkt.vendors.velodyne.stream.stream_kind`, the recorder's
    cheap test); the content decides."""
    kind = stream_kind(batch.payload_size)
    if kind == "data":
        return "data" if data_kind(batch) is not None else None
    if kind == "position":
        return "position" if position_kind(batch) is not None else None
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
        hdl64 = _is_hdl64e(raw)
        ok = _velodyne_shaped(raw) & (known_return_mode(raw.return_mode) | hdl64)
        good = raw.select(ok)
        if np.count_nonzero(hdl64) * 2 > len(raw):
            good = hdl64e_modes(good)
        product = int(np.bincount(good.product_id).argmax())
        modes = sorted({RETURN_MODES[int(m)] for m in np.unique(good.return_mode)})
        try:
            name = detect_model(good).name
            note = None
        except UnknownSensorError as exc:
            name = PRODUCT_NAMES.get(product, f"unknown 0x{product:02x}")
            note = str(exc)
        out = {
            "kind": f"{name} data",
            "model": name,
            "return_mode": modes[0] if len(modes) == 1 else modes,
            "product_id": product,
            "product_name": PRODUCT_NAMES.get(product, f"unknown 0x{product:02x}"),
            "packets": len(batch),
            "malformed_packets": int(np.count_nonzero(~ok)),
            "packet_period_us": _median_period_us(good.timestamp_us),
            "first_timestamp_us": int(good.timestamp_us[0]) if len(good) else None,
        }
        if note:
            out["note"] = note
        if kind == "vlp16":
            out["rotation_hz"] = rotation_frequency_hz(good.azimuth_cdeg, good.return_mode == 0x39) if len(good) else None
            if product == PRODUCT_HDL32E:
                out["note"] = "an early VLP-16 by its packet timing and layout"  # the product byte is shown beside it
        elif note is None and len(good):
            out["rotation_hz"] = rotation_frequency_hz(good.azimuth_cdeg, good.return_mode == 0x39,
                                                       detect_model(good))
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
            from lidarpkt.core.nmea import parse_nmea

            try:
                fix = parse_nmea(first)
                fix_valid = fix.valid
                if fix.utc_ns is not None:
                    import datetime as _dt

                    gps_time = _dt.datetime.fromtimestamp(fix.utc_ns / 1e9, _dt.timezone.utc).isoformat().replace("+00:00", "Z")
            except Exception as exc:  # NMEAError: reported, not raised, in a description
                fix_valid = f"unreadable: {exc}"
        return {
            "kind": "VLP-16 position" if kind == "vlp16" else "HDL-32E position",
            "packets": len(batch),
            "pps_status": PPS_STATUS.get(int(pos.pps_status[0]), int(pos.pps_status[0])),
            "nmea_first": first or None,
            "gps_time_first": gps_time,
            "fix_valid": fix_valid,
            "first_timestamp_us": int(pos.timestamp_us[0]),
        }
    return None


def _is_hdl64e(raw) -> np.ndarray:
    """``bool[N]``: packets whose blocks alternate upper (0xEEFF) and lower (0xDDFF) banks: an HDL-64E's."""
    flags = np.asarray(raw.flag)
    ok = np.ones(flags.shape[0], bool)
    for b in range(flags.shape[1]):  # block by block, done once no packet is left (any other model's: block 1)
        ok &= flags[:, b] == BANK_FLAGS[b % 2]
        if not ok.any():
            break
    return ok


def hdl64e_model(raw) -> VelodyneModel:
    """HDL-64E S2 or S3 by the packet period (6 columns of 48 µs or of 57.6 µs; half in dual mode); S3 when
    the stamps cannot tell."""
    d = _forward_steps_us(raw.timestamp_us)
    if d.size:
        dual = np.count_nonzero(raw.azimuth_cdeg[:, 0] == raw.azimuth_cdeg[:, 2]) * 2 > len(raw)
        period = median(d)
        best = min((HDL64E_S2, HDL64E_S3),
                   key=lambda m: abs(period - m.packet_period_us("dual" if dual else "strongest")))
        return best
    return HDL64E_S3


def product_model(product: int, raw, source: str | None = None) -> VelodyneModel:
    """The model a factory byte names (0x21: HDL-32E or early VLP-16, by timing and layout).

    Raises :class:`~lidarpkt.errors.UnknownSensorError` for a byte no model carries, or one (0x23) that
    names two models the packets cannot tell apart (the error names the option that picks one)."""
    where = f"{source}: " if source else ""
    if product in AMBIGUOUS_PRODUCTS:
        a, b = AMBIGUOUS_PRODUCTS[product]
        raise UnknownSensorError(
            f"{where}Velodyne factory byte 0x{product:02x} is a {a} or a {b}, which the packets cannot tell apart; "
            f"say which with model='{a}' or '{b}' (--model)")
    if product == 0x21:
        return VLP16 if _timing_or_layout_says_vlp16(raw) else HDL32E
    model = model_for_product(product)
    if model is None:
        name = PRODUCT_NAMES.get(product)
        raise UnknownSensorError(
            f"{where}Velodyne factory byte 0x{product:02x}" + (f" ({name})" if name else "") + " names no model "
            f"lidarpkt decodes ({', '.join(m.name for m in MODELS)}); pick one with model=... "
            "(--model) if the byte is wrong")
    return model


def detect_model(raw, source: str | None = None) -> VelodyneModel:
    """The model of a batch of data packets (:class:`~.decode.DataPackets`): the HDL-64E by its block
    layout, the others by their factory byte (the most common one).

    Raises :class:`~lidarpkt.errors.UnknownSensorError` (see :func:`product_model`)."""
    if len(raw) and np.count_nonzero(_is_hdl64e(raw)) * 2 > len(raw):
        return hdl64e_model(raw)
    product = int(np.bincount(np.asarray(raw.product_id)).argmax()) if len(raw) else 0x22
    return product_model(product, raw, source)


def check_product(raw, model: VelodyneModel, source: str | None = None) -> None:
    """Packets of another table model than the one the decoder was given raise
    :class:`~lidarpkt.errors.UnknownSensorError` (model= / a calibration for the wrong sensor)."""
    product = int(np.bincount(np.asarray(raw.product_id)).argmax())
    if product in model.product_ids or product == 0x23 and model.name in ("VLP-32A", "VLP-32B"):
        return
    other = model_for_product(product)
    if other is not None and other.lasers != model.lasers:
        raise UnknownSensorError(
            f"{source + ': ' if source else ''}packets of a {other.name} (factory byte 0x{product:02x}) given to a "
            f"{model.name} decoder; drop model= (--model) or name the sensor's model")


def hdl64e_modes(raw):
    """HDL-64E packets carry a status byte where the others carry the return mode: a packet is dual when
    blocks 0 and 2 share an azimuth (both returns of one upper firing), else strongest."""
    import dataclasses

    dual = raw.azimuth_cdeg[:, 0] == raw.azimuth_cdeg[:, 2]
    modes = np.where(dual, 0x39, 0x37).astype(np.uint8)
    return dataclasses.replace(raw, return_mode=modes)


def vls128_sequence_ns(raw, model: VelodyneModel) -> float | None:
    """The VLS-128's firing sequence from its packet period: 20 channels of 2.665 µs (packets every
    160 µs; dual every 53.3 µs) before firmware 5.2.3.0, of 2.89 µs (173.4 µs) after; ``None`` if the
    stamps cannot tell."""
    d = _forward_steps_us(raw.timestamp_us)
    if not d.size:
        return None
    dual = np.count_nonzero(raw.return_mode == 0x39) * 2 > len(raw)
    period = median(d) * (3 if dual else 1)
    if 153 < period < 180:
        return 20 * (8000.0 / 3.0 if period < 167 else 2890.0)
    return None


def _timing_or_layout_says_vlp16(raw) -> bool:
    ok = raw.flag_ok & known_return_mode(raw.return_mode)
    raw = raw.select(ok) if np.any(ok) else raw
    dual = median(raw.return_mode) == 0x39 if len(raw) else False
    expected = VLP16.packet_period_us("dual" if dual else "strongest")
    hdl = HDL32E_PACKET_PERIOD_US / 2 if dual else HDL32E_PACKET_PERIOD_US
    period = _median_period_us(raw.timestamp_us)
    if period is not None:
        if abs(period - expected) < 0.05 * expected:
            return True
        if abs(period - hdl) < 0.05 * hdl:
            return False
        d = _forward_steps_us(raw.timestamp_us)
        fits = lambda p: np.abs(d - np.rint(d / p) * p) <= 3  # noqa: E731 - µs stamps jitter by 1
        n_vlp, n_hdl = int(np.count_nonzero(fits(expected))), int(np.count_nonzero(fits(hdl)))
        if n_vlp != n_hdl:
            return n_vlp > n_hdl
    return _layout_says_vlp16(raw)
