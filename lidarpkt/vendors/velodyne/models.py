"""The Velodyne models lidarpkt decodes, as data: one frozen :class:`VelodyneModel` per model.

Every spinning Velodyne sends the same 1206-byte data packet (12 blocks of a flag, an azimuth and
32 channels; a timestamp, a return-mode byte, a factory byte). The models differ in how their
lasers fill it, and that is all a row says: how many lasers, how many blocks make one firing column
(1; 2 on the HDL-64E, upper bank 0xEEFF and lower 0xDDFF; 4 on the VLS-128, banks 0xEEFF, 0xDDFF,
0xCCFF, 0xBBFF) or how many columns one block holds (2 on the 16-laser Pucks), the firing time of
each laser inside its column, the column period, the distance unit, the dual-return block layout,
and the stock calibration (elevation and azimuth offset per laser, beam-origin offsets).
:mod:`lidarpkt.vendors.velodyne.layout` derives every per-block, per-channel table from a row.

Sources: the user manuals' "Data Packet Format", "Laser Angles" / "Laser ID" and "Firing Timing"
tables (VLP-16 / Puck LITE, Puck Hi-Res, HDL-32E, VLP-32C, VLS-128 / Alpha Prime, HDL-64E S2 and
S3), as collected in ../shared/REFERENCE.md; and velodyne_decoder 3.1.0's tables of the same
(``calib_db.cpp``: stock elevations, azimuth offsets, focal distances and the HDL-32E's and Hi-Res'
published vertical offsets; ``packet_decoder.cpp``: timing tables).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

from lidarpkt.errors import PacketFormatError, UnknownSensorError

#: Return mode bytes of the 1206-byte packet family (byte 1204).
RETURN_MODES = {0x37: "strongest", 0x38: "last", 0x39: "dual"}
#: Product id bytes (byte 1205) of the Velodyne models we know by name.
PRODUCT_NAMES = {0x21: "HDL-32E", 0x22: "VLP-16", 0x23: "VLP-32A/B", 0x24: "Puck Hi-Res", 0x28: "VLP-32C",
                 0x31: "Velarray", 0xA1: "VLS-128"}
#: The HDL-32E (product 0x21, as early VLP-16s also say) sends a packet every 12 × 46.08 µs: the
#: period that tells such a VLP-16 from a real HDL-32E.
HDL32E_PACKET_PERIOD_US = 12 * 46.080

#: Block flags (bytes FF EE, FF DD, ... read as u16 LE): the laser bank a block holds.
BANK_FLAGS = (0xEEFF, 0xDDFF, 0xCCFF, 0xBBFF)

# The packet family's layout (lidarpkt.vendors.velodyne.packet declares the bytes): a model's firings fill it.
_BLOCKS_PER_PACKET = 12
_CHANNELS_PER_BLOCK = 32


@dataclass(frozen=True)
class VelodyneModel:
    """What lidarpkt needs to know about one Velodyne model.

    Attributes:
        name: ``"VLP-16"``, ``"HDL-32E"``, ...
        product_ids: the factory bytes this model's packets carry (the first is the official one); empty for
            a model told apart otherwise (the HDL-64E, whose last two bytes are a status cycle; the Puck
            LITE and the Alpha Prime, which say VLP-16 and VLS-128 and are chosen by name).
        lasers: lasers of the model.
        elevation_deg: stock elevation of each laser id, degrees.
        sequence_ns: duration of one firing sequence (one frame column), ns (55 296 on the VLP-16).
        firing_ns: the manual's delay between consecutive firings of a sequence, ns (2 304 on the
            VLP-16); ``laser_firing_ns`` gives each laser's.
        blocks_per_packet: data blocks per packet (12).
        sequences_per_block: firing sequences (columns) one block holds in single-return modes (2 on
            the 16-laser Pucks, else 1).
        beam_origin_forward_m: lever arm of the stock calibration's vertical beam offsets
            (``vert_offset = beam_origin_forward_m · tan(−ω)``), metres.
        distance_resolution_m: metres per raw distance unit (0.002 or 0.004).
        grid_resolution_deg: the azimuth grid a frame is resampled on by default, degrees.
        blocks_per_column: consecutive blocks that make one column (1; 2 HDL-64E; 4 VLS-128).
        laser_firing_ns: firing time of each laser id after its column's first firing, ns (``None``:
            ``firing_ns × laser id``).
        column_offset_ns: time of a packet's first column after its timestamp, ns (negative on the VLS-128,
            whose timestamp is taken 7 µs into a sequence).
        dual_layout: where dual mode puts the two returns: ``"pairs"`` (blocks 2k last, 2k+1 strongest:
            half the columns), ``"upper_lower"`` (HDL-64E: blocks 4k, 4k+1 strongest upper/lower,
            4k+2, 4k+3 last), ``"banks"`` (VLS-128: blocks 2k last and 2k+1 strongest of bank k,
            blocks 0–7, one column per packet).
        azimuth_offset_deg: stock azimuth offset (rot_correction) of each laser id, degrees (``None``: 0).
        vert_offset_m: stock vertical beam offsets, metres (``None``: from ``beam_origin_forward_m``).
        default_calibration: ``False`` for a model without a usable stock calibration (the HDL-64E,
            calibrated per unit: its packets carry the calibration).
    """

    name: str
    product_ids: tuple[int, ...]
    lasers: int
    elevation_deg: tuple[float, ...]
    sequence_ns: float
    firing_ns: float
    blocks_per_packet: int
    sequences_per_block: int
    beam_origin_forward_m: float
    distance_resolution_m: float
    grid_resolution_deg: float
    blocks_per_column: int = 1
    laser_firing_ns: tuple[float, ...] | None = None
    column_offset_ns: float = 0.0
    dual_layout: str = "pairs"
    azimuth_offset_deg: tuple[float, ...] | None = None
    vert_offset_m: tuple[float, ...] | None = None
    default_calibration: bool = True

    def __post_init__(self) -> None:
        if len(self.elevation_deg) != self.lasers:
            raise PacketFormatError(f"{self.name}: {len(self.elevation_deg)} elevations for {self.lasers} lasers")
        if self.blocks_per_packet != _BLOCKS_PER_PACKET or (
                self.lasers * self.sequences_per_block != _CHANNELS_PER_BLOCK * self.blocks_per_column) or (
                self.blocks_per_packet % self.blocks_per_column):
            raise PacketFormatError(f"{self.name}: {self.blocks_per_packet} blocks of {self.lasers} × "
                                    f"{self.sequences_per_block} firings do not fill the 12 × 32-channel packet")
        for name in ("laser_firing_ns", "azimuth_offset_deg", "vert_offset_m"):
            value = getattr(self, name)
            if value is not None and len(value) != self.lasers:
                raise PacketFormatError(f"{self.name}: {len(value)} {name} for {self.lasers} lasers")
        if self.laser_firing_ns is None and self.lasers // self.blocks_per_column * self.firing_ns > self.sequence_ns:
            raise PacketFormatError(f"{self.name}: {self.lasers} firings of {self.firing_ns} ns exceed a sequence")
        if self.dual_layout not in ("pairs", "upper_lower", "banks"):
            raise PacketFormatError(f"{self.name}: unknown dual layout {self.dual_layout!r}")

    @property
    def sequences_per_packet(self) -> int:
        """Firing sequences (columns) of a single-return packet (24 on the VLP-16, 12 on 32-laser models)."""
        return self.blocks_per_packet // self.blocks_per_column * self.sequences_per_block

    @functools.cached_property  # asked for every frame (its pixels' time offsets)
    def laser_offsets_ns(self) -> tuple[float, ...]:
        """Firing time of each laser id after its column's first firing, ns."""
        if self.laser_firing_ns is not None:
            return self.laser_firing_ns
        return tuple(float(self.firing_ns * i) for i in range(self.lasers))

    def columns_per_packet(self, mode: str) -> int:
        """Frame columns one packet carries in return mode ``mode`` (VLP-16: 24, dual 12; VLS-128: 3, dual 1)."""
        if mode != "dual":
            return self.sequences_per_packet
        if self.dual_layout == "banks":
            return 1
        return self.sequences_per_packet // 2

    def packet_period_ns(self, mode: str) -> int:
        """Time between consecutive data packets in return mode ``mode``, ns (1 327 104, dual 663 552)."""
        return int(round(self.columns_per_packet(mode) * self.sequence_ns))

    def packet_period_us(self, mode: str) -> float:
        """:meth:`packet_period_ns` in µs (1327.104, dual 663.552)."""
        return self.packet_period_ns(mode) / 1000.0

    def columns_per_rotation(self, frequency_hz: float | None) -> int:
        """Firing sequences of one rotation at ``frequency_hz`` (1808 at 10 Hz; 10 Hz when unknown)."""
        return int(round(1e9 / ((frequency_hz or 10.0) * self.sequence_ns)))

    def with_sequence_ns(self, sequence_ns: float) -> "VelodyneModel":
        """The same model with every firing time scaled to a firing sequence of ``sequence_ns`` (the
        VLS-128, whose firmware sets its channel time: 2.665 µs, from firmware 5.2.3.0 2.89 µs)."""
        k = sequence_ns / self.sequence_ns
        return dataclasses.replace(
            self, sequence_ns=sequence_ns, firing_ns=self.firing_ns * k,
            laser_firing_ns=tuple(t * k for t in self.laser_offsets_ns), column_offset_ns=self.column_offset_ns * k)


VLP16 = VelodyneModel(
    name="VLP-16",
    product_ids=(0x22, 0x21),  # 0x21: early (2014) units, which say HDL-32E
    lasers=16,
    elevation_deg=(-15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0),
    sequence_ns=55_296,
    firing_ns=2_304,
    blocks_per_packet=12,
    sequences_per_block=2,
    beam_origin_forward_m=0.04191,
    distance_resolution_m=0.002,
    grid_resolution_deg=0.2,
)

#: The Puck LITE: a VLP-16 in a lighter housing; same packets, product byte 0x22 (chosen by name).
PUCK_LITE = dataclasses.replace(VLP16, name="Puck LITE", product_ids=())

#: Puck Hi-Res: the VLP-16's timing, lasers from −10° to +10° in 1.33° steps; published vertical offsets.
PUCK_HI_RES = dataclasses.replace(
    VLP16, name="Puck Hi-Res", product_ids=(0x24,),
    elevation_deg=(-10.0, 0.667, -8.667, 2.0, -7.333, 3.333, -6.0, 4.667, -4.667, 6.0, -3.333, 7.333, -2.0, 8.667,
                   -0.667, 10.0),
    vert_offset_m=(7.4e-3, -0.9e-3, 6.5e-3, -1.8e-3, 5.5e-3, -2.7e-3, 4.6e-3, -3.7e-3, 3.7e-3, -4.6e-3, 2.7e-3,
                   -5.5e-3, 1.8e-3, -6.5e-3, 0.9e-3, -7.4e-3),
    grid_resolution_deg=0.2,
)

#: HDL-32E: 32 lasers, one firing per channel, 1.152 µs apart; 32 × 1.152 + 9.216 µs recharge = 46.08 µs.
HDL32E = VelodyneModel(
    name="HDL-32E", product_ids=(0x21,), lasers=32,
    elevation_deg=(-30.67, -9.33, -29.33, -8.0, -28.0, -6.67, -26.67, -5.33, -25.33, -4.0, -24.0, -2.67, -22.67,
                   -1.33, -21.33, 0.0, -20.0, 1.33, -18.67, 2.67, -17.33, 4.0, -16.0, 5.33, -14.67, 6.67, -13.33,
                   8.0, -12.0, 9.33, -10.67, 10.67),
    sequence_ns=46_080, firing_ns=1_152, blocks_per_packet=12, sequences_per_block=1,
    beam_origin_forward_m=0.02883, distance_resolution_m=0.002, grid_resolution_deg=0.16,
    vert_offset_m=(17.17e-3, 4.76e-3, 16.27e-3, 4.07e-3, 15.4e-3, 3.38e-3, 14.54e-3, 2.7e-3, 13.71e-3, 2.02e-3,
                   12.89e-3, 1.35e-3, 12.09e-3, 0.67e-3, 11.31e-3, 0.0, 10.54e-3, -0.67e-3, 9.78e-3, -1.35e-3,
                   9.04e-3, -2.02e-3, 8.3e-3, -2.7e-3, 7.58e-3, -3.38e-3, 6.86e-3, -4.07e-3, 6.15e-3, -4.76e-3,
                   5.45e-3, -5.45e-3),
)

_VLP32_PAIRS = tuple(float(2_304 * (i // 2)) for i in range(32))  # lasers fire in pairs, 2.304 µs apart

#: VLP-32C: 32 lasers fired in pairs, 55.296 µs sequences, 4 mm distances.
VLP32C = VelodyneModel(
    name="VLP-32C", product_ids=(0x28,), lasers=32,
    elevation_deg=(-25.0, -1.0, -1.667, -15.639, -11.31, 0.0, -0.667, -8.843, -7.254, 0.333, -0.333, -6.148,
                   -5.333, 1.333, 0.667, -4.0, -4.667, 1.667, 1.0, -3.667, -3.333, 3.333, 2.333, -2.667, -3.0, 7.0,
                   4.667, -2.333, -2.0, 15.0, 10.333, -1.333),
    azimuth_offset_deg=(-1.4, 4.2, -1.4, 1.4, -1.4, 1.4, -4.2, 1.4, -1.4, 4.2, -1.4, 1.4, -4.2, 1.4, -4.2, 1.4,
                        -1.4, 4.2, -1.4, 4.2, -4.2, 1.4, -1.4, 1.4, -1.4, 1.4, -1.4, 4.2, -4.2, 1.4, -1.4, 1.4),
    sequence_ns=55_296, firing_ns=2_304, blocks_per_packet=12, sequences_per_block=1,
    beam_origin_forward_m=0.0424, distance_resolution_m=0.004, grid_resolution_deg=0.2,
    laser_firing_ns=_VLP32_PAIRS,
)

#: VLP-32A and VLP-32B share the factory byte 0x23: nothing in a packet tells them apart.
VLP32A = dataclasses.replace(
    VLP32C, name="VLP-32A", product_ids=(0x23,),
    elevation_deg=(-14.3, 0.8337, 12.5, -0.5, -10.7, 2.167, 8.9, -1.834, -7.0, 1.167, 6.0, -0.167, -4.9, 2.5, 3.8,
                   -1.5, -2.167, 10.7, 1.834, -8.9, -2.5, 4.9, 1.5, -3.8, -0.834, 14.3, 0.5, -12.5, -1.167, 7.0,
                   0.167, -6.0),
    azimuth_offset_deg=(-1.2, 1.2, -1.2, 1.2, -1.2, 1.2, -1.2, 1.2, -1.2, 3.6, -1.2, 3.6, -1.2, 3.6, -1.2, 3.6,
                        -1.2, 1.2, -1.2, 1.2, -3.6, 1.2, -3.6, 1.2, -1.2, 1.2, -1.2, 1.2, -3.6, 1.2, -3.6, 1.2),
)
#: VLP-32B: the VLP-32C's lasers under the VLP-32A's factory byte.
VLP32B = dataclasses.replace(VLP32C, name="VLP-32B", product_ids=(0x23,))

_VLS128_CHANNEL_NS = 2_890  # firmware ≥ 5.2.3.0; earlier 2.665 µs (VelodyneModel.with_sequence_ns)
#: VLS-128 / Alpha Prime: 128 lasers in 4 banks of 32 (one block each), fired 8 at a time: laser l in
#: firing group l // 8 + 2 · (l // 64) of a 20-group sequence (groups 8, 9 and 18, 19 recharge).
VLS128 = VelodyneModel(
    name="VLS-128", product_ids=(0xA1,), lasers=128,
    elevation_deg=(-11.742, -1.99, 3.4, -5.29, -0.78, 4.61, -4.08, 1.31, -6.5, -1.11, 4.28, -4.41, 0.1, 6.48, -3.2,
                   2.19, -3.86, 1.53, -9.244, -1.77, 2.74, -5.95, -0.56, 4.83, -2.98, 2.41, -6.28, -0.89, 3.62,
                   -5.07, 0.32, 7.58, -0.34, 5.18, -3.64, 1.75, -25.0, -2.43, 2.96, -5.73, 0.54, 9.7, -2.76, 2.63,
                   -7.65, -1.55, 3.84, -4.85, 3.18, -5.51, -0.12, 5.73, -4.3, 1.09, -16.042, -2.21, 4.06, -4.63,
                   0.76, 15.0, -3.42, 1.97, -6.85, -1.33, -5.62, -0.23, 5.43, -3.53, 0.98, -19.582, -2.32, 3.07,
                   -4.74, 0.65, 11.75, -2.65, 1.86, -7.15, -1.44, 3.95, -2.1, 3.29, -5.4, -0.01, 4.5, -4.19, 1.2,
                   -13.565, -1.22, 4.17, -4.52, 0.87, 6.08, -3.31, 2.08, -6.65, 1.42, -10.346, -1.88, 3.51, -6.06,
                   -0.67, 4.72, -3.97, 2.3, -6.39, -1.0, 4.39, -5.18, 0.21, 6.98, -3.09, 4.98, -3.75, 1.64, -8.352,
                   -2.54, 2.85, -5.84, -0.45, 8.43, -2.87, 2.52, -6.17, -1.66, 3.73, -4.96, 0.43),
    azimuth_offset_deg=(-6.354, -4.548, -2.732, -0.911, 0.911, 2.732, 4.548, 6.354) * 16,
    sequence_ns=20 * _VLS128_CHANNEL_NS, firing_ns=_VLS128_CHANNEL_NS, blocks_per_packet=12, sequences_per_block=1,
    beam_origin_forward_m=0.05863, distance_resolution_m=0.004, grid_resolution_deg=0.2, blocks_per_column=4,
    laser_firing_ns=tuple(float(_VLS128_CHANNEL_NS * (i // 8 + 2 * (i // 64))) for i in range(128)),
    column_offset_ns=-7_000.0, dual_layout="banks",
)
#: The Alpha Prime is the VLS-128 (same factory byte 0xA1; chosen by name).
ALPHA_PRIME = dataclasses.replace(VLS128, name="Alpha Prime", product_ids=())


def _hdl64e(name: str, sequence_ns: int, step_ns: int, pattern_ns: tuple[int, ...]) -> VelodyneModel:
    # each bank fires its 32 lasers 4 at a time; upper and lower banks fire together
    firing = tuple(float(step_ns * ((i % 32) // 4) + pattern_ns[i % 4]) for i in range(64))
    return VelodyneModel(
        name=name, product_ids=(), lasers=64, elevation_deg=(0.0,) * 64, sequence_ns=sequence_ns, firing_ns=step_ns,
        blocks_per_packet=12, sequences_per_block=1, beam_origin_forward_m=0.0, distance_resolution_m=0.002,
        grid_resolution_deg=0.2, blocks_per_column=2, laser_firing_ns=firing, dual_layout="upper_lower",
        default_calibration=False)


#: HDL-64E S2: 64 lasers in an upper (0xEEFF) and a lower (0xDDFF) block per column, 48 µs columns.
HDL64E_S2 = _hdl64e("HDL-64E S2", 48_000, 6_000, (0, 1_260, 2_460, 3_660))
#: HDL-64E S3: as the S2, 57.6 µs columns.
HDL64E_S3 = _hdl64e("HDL-64E S3", 57_600, 7_200, (0, 1_300, 2_500, 3_700))

#: Every model lidarpkt decodes.
MODELS: tuple[VelodyneModel, ...] = (VLP16, PUCK_LITE, PUCK_HI_RES, HDL32E, VLP32C, VLP32A, VLP32B, VLS128,
                                     ALPHA_PRIME, HDL64E_S2, HDL64E_S3)
#: Factory bytes that name more than one model: the option that picks one says so.
AMBIGUOUS_PRODUCTS = {0x23: ("VLP-32A", "VLP-32B")}


def model_for_product(product_id: int) -> VelodyneModel | None:
    """The model whose packets carry ``product_id`` (0x21 gives the VLP-16: detection tells an
    HDL-32E apart by its timing), ``None`` for a byte no model (or more than one) carries."""
    if product_id in AMBIGUOUS_PRODUCTS:
        return None
    for model in MODELS:
        if product_id in model.product_ids:
            return model
    return None


def model_named(name: str) -> VelodyneModel:
    """The model called ``name`` (``"VLP-16"``, ``"VLS-128"``, ``"HDL-64E S3"``; case, spaces and
    dashes ignored). Raises :class:`~lidarpkt.errors.UnknownSensorError` if unknown."""
    key = name.replace(" ", "").replace("-", "").replace("_", "").lower()
    for model in MODELS:
        if model.name.replace(" ", "").replace("-", "").lower() == key:
            return model
    raise UnknownSensorError(f"model {name!r}: no such Velodyne model; lidarpkt decodes "
                             f"{', '.join(m.name for m in MODELS)}")
