"""VLP-16 firing times and the azimuth of every firing.

Manual ("Precision Azimuth Calculation", "Firing timing"): a firing sequence lasts
55.296 µs and each of its 16 lasers fires 2.304 µs after the previous. In single-return
modes block ``b`` holds firing sequences ``2b`` and ``2b+1``; in dual mode blocks ``2k``
and ``2k+1`` hold the two returns of the same two sequences, which have the times of
single-mode block ``k``.

The azimuth of a firing is the block azimuth advanced by the rotation rate times the
firing's delay after the block's first firing. The rate is measured inside each packet
(first to last block), exactly as velodyne_decoder 3.1.0 does it, with its float32
arithmetic, so that both give the same 0.01° for every firing.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.core.median import median
from .models import VLP16, VelodyneModel
from .packet import BLOCKS_PER_PACKET, CHANNELS_PER_BLOCK

SEQUENCE_NS = VLP16.sequence_ns  # 55.296 µs, exact in ns
FIRING_NS = VLP16.firing_ns  # 2.304 µs
LASERS = VLP16.lasers

# Single-mode delay of block b, channel j after the packet timestamp, ns: [12, 32].
_b, _j = np.meshgrid(np.arange(BLOCKS_PER_PACKET), np.arange(CHANNELS_PER_BLOCK), indexing="ij")
_SEQ = VLP16.sequences_per_block * _b + _j // LASERS  # firing sequence of block b, channel j
FIRING_OFFSET_NS = (SEQUENCE_NS * _SEQ + FIRING_NS * (_j % LASERS)).astype(np.int64)
# The same in float32 seconds, as velodyne_decoder tabulates them (double → float).
_FIRING_OFFSET_S32 = (FIRING_OFFSET_NS.astype(np.float64) * 1e-9).astype(np.float32)


def time_block(dual: np.ndarray | bool) -> np.ndarray:
    """``int[..., 12]``: the single-mode block whose times block i has (i, or i // 2 in dual mode)."""
    i = np.arange(BLOCKS_PER_PACKET)
    return np.where(np.asarray(dual)[..., None], i // 2, i)


def firing_offset_ns(dual: np.ndarray) -> np.ndarray:
    """``int64[N, 12, 32]`` delay of every firing after its packet's timestamp, ns. ``dual``: ``bool[N]``."""
    return FIRING_OFFSET_NS[time_block(dual)]


# Delay of every firing after its block's first firing, float32 seconds as velodyne_decoder
# computes it (time − t0 with both from its float32 table), per block: [12, 32] for each mode.
_DT_SINGLE = _FIRING_OFFSET_S32 - _FIRING_OFFSET_S32[:, :1]
_DT_DUAL = _DT_SINGLE[np.arange(BLOCKS_PER_PACKET) // 2]
_DURATION_SINGLE = _FIRING_OFFSET_S32[BLOCKS_PER_PACKET - 1, 0] - _FIRING_OFFSET_S32[0, 0]
_DURATION_DUAL = _FIRING_OFFSET_S32[(BLOCKS_PER_PACKET - 1) // 2, 0] - _FIRING_OFFSET_S32[0, 0]
_DT_SINGLE.flags.writeable = False
_DT_DUAL.flags.writeable = False


def firing_azimuth_cdeg(azimuth_cdeg: np.ndarray, dual: np.ndarray | bool, blocks: slice = slice(None)) -> np.ndarray:
    """``uint16[N, B, 32]`` azimuth of every firing, 0.01°, in [0, 36000).

    ``azimuth_cdeg``: ``[N, 12]`` block azimuths; ``dual``: ``bool[N]`` (or one bool for all)
    dual-return packets; ``blocks``: compute only these blocks (e.g. ``slice(0, None, 2)``: one
    block of each dual pair), all 12 by default.
    lround(block_az + rate·dt) mod 36000 with rate = (last − first block azimuth, mod 36000)
    over the time between those blocks, computed in float32 like velodyne_decoder; ties
    round half away from zero (:func:`packet_rate_cdeg_s_vlp16`, :func:`firing_azimuths`).
    """
    az = np.asarray(azimuth_cdeg)
    rate = packet_rate_cdeg_s_vlp16(az, dual)
    if np.ndim(dual) == 0:
        dt = firing_dt_s(bool(dual))[blocks][None]  # [1, B, 32]
    else:
        dual = np.asarray(dual, dtype=bool)
        dt = np.where(dual[:, None, None], _DT_DUAL[blocks], _DT_SINGLE[blocks])
    return firing_azimuths(az[:, blocks], rate, dt, general=bool(az.size and int(az.max()) > 36000))


def packet_rate_cdeg_s_vlp16(azimuth_cdeg: np.ndarray, dual: np.ndarray | bool) -> np.ndarray:
    """``float32[N]`` rotation rate inside each VLP-16 packet, 0.01°/s: the last block's azimuth advance over the
    first's (mod 36000) over the time between their first firings, in velodyne_decoder's float32 arithmetic.
    ``dual``: ``bool[N]``, or one bool for all."""
    az = np.asarray(azimuth_cdeg)
    diff = ((az[:, -1].astype(np.int32) - az[:, 0].astype(np.int32)) + 36000) % 36000
    if np.ndim(dual) == 0:
        duration = _DURATION_DUAL if dual else _DURATION_SINGLE
    else:
        duration = np.where(np.asarray(dual, dtype=bool), _DURATION_DUAL, _DURATION_SINGLE).astype(np.float32)
    return diff.astype(np.float32) / duration  # cdeg/s, float32


def firing_dt_s(dual: bool) -> np.ndarray:
    """``float32[12, 32]``: the delay of every firing after its block's first, seconds, as velodyne_decoder
    tabulates it (dual: block 2k and 2k + 1 share the times of single-mode block k). Read-only."""
    return _DT_DUAL if dual else _DT_SINGLE


def firing_azimuths(block_azimuth_cdeg: np.ndarray, rate_cdeg_s: np.ndarray, dt_s: np.ndarray, *,
                    general: bool = False) -> np.ndarray:
    """``uint16[N, B, 32]``: lround(block azimuth + rate · dt) mod 36000 of every firing, summed in float32 in
    velodyne_decoder's order (rate · dt, + azimuth, + 36000, + 0.5, truncated). ``block_azimuth_cdeg``:
    ``[N, B]``; ``rate_cdeg_s``: ``float32[N]``; ``dt_s``: ``float32[B, 32]`` (or broadcast to ``[N, B, 32]``).
    ``general``: some block azimuth is above 36000 (damaged), so the sum may pass 72000: the integer
    modulo instead of one subtraction. (The compiled ``velodyne_columns`` makes the same sum per firing.)"""
    value = rate_cdeg_s[:, None, None] * dt_s
    value += np.asarray(block_azimuth_cdeg).astype(np.float32)[:, :, None]
    value += np.float32(36000)
    # lround of a positive value: in [36000, 72000) float32 steps are 1/256 or 1/128, so + 0.5 is
    # exact and truncation is the floor
    value += np.float32(0.5)
    if general:  # not a valid block azimuth: the general integer path
        rounded = value.astype(np.int32)
        rounded %= 36000
        return rounded.astype(np.uint16)
    # floor(value) is in [36000, 36000 + 36000 + 36000 · 90 µs / 553 µs): minus 36000 (exact in
    # float32) it fits a uint16, and "mod 36000" is min(x, x − 36000 wrapped): no integer division
    value -= np.float32(36000)
    rounded = value.astype(np.uint16)
    np.minimum(rounded, rounded - np.uint16(36000), out=rounded)
    return rounded


def rotation_frequency_hz(azimuth_cdeg: np.ndarray, dual: np.ndarray, model: VelodyneModel = VLP16) -> float | None:
    """Rotation rate in Hz (2 decimals) from the azimuth advance inside packets (median over the
    packets), ``None`` if unmeasurable. ``azimuth_cdeg``: ``[N, 12]`` block azimuths; ``dual``: ``bool[N]``."""
    diff = (azimuth_cdeg[:, -1].astype(np.int64) - azimuth_cdeg[:, 0]) % 36000
    if model.dual_layout == "banks":  # the VLS-128's blocks share 3 (dual: 1) azimuths: measured between packets
        return None
    if model.sequences_per_block == 2:
        # firing sequences between the first and the last block (dual: block pairs share their firings)
        b, s = model.blocks_per_packet, model.sequences_per_block
        seqs = np.where(dual, (b // 2 - 1) * s, (b - 1) * s)
        rate = diff / (seqs * model.sequence_ns)  # 0.01° per ns
    else:
        from .layout import packet_layout

        span_ns = np.where(dual, float(packet_layout(model, "dual").rate_span_s32),
                           float(packet_layout(model, "strongest").rate_span_s32)) * 1e9
        rate = diff / span_ns
    hz = median(rate) * 1e9 / 36000.0 if rate.size else 0.0
    return round(hz, 2) if hz > 0 else None


def round_azimuth_cdeg(value: np.ndarray, block_azimuth_cdeg: np.ndarray) -> np.ndarray:
    """``uint16``: lround(block azimuth + ``value``) mod 36000, summed in float32 in velodyne_decoder's order
    (``value`` = rate · dt, float32; ``block_azimuth_cdeg`` broadcast to it). Modifies ``value``."""
    value += block_azimuth_cdeg.astype(np.float32)
    value += np.float32(36000)
    value += np.float32(0.5)  # lround of a positive value: + 0.5 is exact in [36000, 72000), then floor
    rounded = value.astype(np.int32)
    rounded %= 36000
    return rounded.astype(np.uint16)


def packet_rate_cdeg_s(azimuth_cdeg: np.ndarray, layout) -> np.ndarray:
    """``float32[N]`` rotation rate inside each packet, 0.01°/s: the last block's azimuth advance over block 0's
    (mod 36000), over the time between their firings (velodyne_decoder's float32 arithmetic)."""
    az = np.asarray(azimuth_cdeg)
    diff = (az[:, -1].astype(np.int32) - az[:, 0].astype(np.int32) + 36000) % 36000
    return diff.astype(np.float32) / layout.rate_span_s32


def interpacket_rate_cdeg_s(first_azimuth_cdeg: np.ndarray, timestamp_us: np.ndarray, layout, period_us: float,
                            prev_az: int | None, prev_us: int | None) -> tuple[np.ndarray, int, int]:
    """VLS-128: ``float32[N]`` rotation rate of each packet from the advance of the first block's azimuth since
    the previous packet (``prev_az`` / ``prev_us``: the last packet of an earlier batch), over the packets'
    time (the packets a lost stretch skipped counted by the stamps); the first packet of a stream takes the
    next one's. Returns the rates and the new ``prev_az``, ``prev_us``."""
    az = np.asarray(first_azimuth_cdeg).astype(np.int64)
    ts = np.asarray(timestamp_us).astype(np.int64)
    n = az.size
    if prev_az is not None:
        az_prev = np.concatenate([[prev_az], az[:-1]])
        ts_prev = np.concatenate([[prev_us], ts[:-1]])
    else:
        az_prev, ts_prev = np.concatenate([az[:1], az[:-1]]), np.concatenate([ts[:1], ts[:-1]])
    diff = (az - az_prev) % 36000
    steps = np.maximum(np.rint(((ts - ts_prev) % 3_600_000_000) / period_us), 1).astype(np.int64)
    rate = diff.astype(np.float32) / (layout.rate_span_s32 * steps.astype(np.float32))
    if prev_az is None:
        rate[0] = rate[1] if n > 1 else 0.0
    return rate.astype(np.float32), int(az[-1]), int(ts[-1])


#: (laser offsets, row order) -> the widest read-only image of row offsets made so far (see row_offsets_ns)
_ROW_OFFSETS: dict[tuple[bytes, bytes], np.ndarray] = {}


def row_offsets_ns(model: VelodyneModel, row_laser: np.ndarray, width: int) -> np.ndarray:
    """``int64[L, width]``, read-only: each row's firing delay after its column's first firing, ns (the model's
    laser offsets; row ``i`` is laser ``row_laser[i]``), in every column. A view of one image per model and
    row order, shared by every decoder (a capture of many sensors makes one)."""
    laser_ns = np.asarray(model.laser_offsets_ns)
    key = (laser_ns.tobytes(), np.asarray(row_laser).tobytes())
    image = _ROW_OFFSETS.get(key)
    if image is None or image.shape[1] < width:
        offsets = np.rint(laser_ns[row_laser]).astype(np.int64)
        image = np.empty((len(offsets), max(width, 4096)), np.int64)
        image[...] = offsets[:, None]
        image.flags.writeable = False
        _ROW_OFFSETS[key] = image
    return image[:, :width]
