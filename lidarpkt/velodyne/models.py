"""The Velodyne models lidarpkt decodes, as data: one frozen :class:`VelodyneModel` per model.

Packet, timing, frames, calibration and detection read their facts here (lasers, product
ids, firing timing, blocks per packet, packet periods, the default calibration) instead of
literals, so that another model of the same 1206-byte packet family (12 blocks of 32
channels) is a row of :data:`MODELS` plus its tests. Only the VLP-16 is in the table today.

Sources: the VLP-16 user manual ("Data Packet Format", "Laser Angles", "Firing Timing",
"Precision Azimuth Calculation") and velodyne_decoder 3.1.0's stock VLP-16 calibration
(elevations, and vertical beam offsets of 41.91 mm · tan(−ω)); see ../shared/REFERENCE.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import PacketFormatError, UnknownSensorError

#: Return mode bytes of the 1206-byte packet family (byte 1204).
RETURN_MODES = {0x37: "strongest", 0x38: "last", 0x39: "dual"}
#: Product id bytes (byte 1205) of the Velodyne models we know by name, in the table or not.
PRODUCT_NAMES = {0x21: "HDL-32E", 0x22: "VLP-16", 0x24: "Puck Hi-Res", 0x28: "VLP-32C", 0x31: "Velarray",
                 0xA1: "VLS-128"}
#: The HDL-32E (product 0x21, as early VLP-16s also say) sends a packet every 12 × 46.08 µs: the
#: period that tells such a VLP-16 from a real HDL-32E. Not a table row: lidarpkt does not decode it.
HDL32E_PACKET_PERIOD_US = 12 * 46.080

# The packet family's layout (lidarpkt.velodyne.packet declares the bytes): a model's firings fill it.
_BLOCKS_PER_PACKET = 12
_CHANNELS_PER_BLOCK = 32


@dataclass(frozen=True)
class VelodyneModel:
    """What lidarpkt needs to know about one Velodyne model.

    Attributes:
        name: ``"VLP-16"``.
        product_ids: the product id bytes this model's packets carry (the first is the official one).
        lasers: lasers per firing sequence.
        elevation_deg: elevation of each laser id (firing order), degrees.
        sequence_ns: duration of one firing sequence, ns (55 296 on the VLP-16).
        firing_ns: delay between consecutive lasers of a sequence, ns (2 304).
        blocks_per_packet: data blocks per packet (12).
        sequences_per_block: firing sequences per block in single-return modes (2).
        beam_origin_forward_m: lever arm of the stock calibration's vertical beam offsets
            (``vert_offset = beam_origin_forward_m · tan(−ω)``), metres.
        distance_resolution_m: metres per raw distance unit.
        grid_resolution_deg: the azimuth grid a frame is resampled on by default, degrees.
    """

    name: str
    product_ids: tuple[int, ...]
    lasers: int
    elevation_deg: tuple[float, ...]
    sequence_ns: int
    firing_ns: int
    blocks_per_packet: int
    sequences_per_block: int
    beam_origin_forward_m: float
    distance_resolution_m: float
    grid_resolution_deg: float

    def __post_init__(self) -> None:
        if len(self.elevation_deg) != self.lasers:
            raise PacketFormatError(f"{self.name}: {len(self.elevation_deg)} elevations for {self.lasers} lasers")
        layout = (self.blocks_per_packet, self.lasers * self.sequences_per_block)
        if layout != (_BLOCKS_PER_PACKET, _CHANNELS_PER_BLOCK):
            raise PacketFormatError(f"{self.name}: {self.blocks_per_packet} blocks of {self.lasers} × "
                                    f"{self.sequences_per_block} firings do not fill the 12 × 32-channel packet")
        if self.lasers * self.firing_ns > self.sequence_ns:
            raise PacketFormatError(f"{self.name}: {self.lasers} firings of {self.firing_ns} ns exceed a sequence")

    @property
    def sequences_per_packet(self) -> int:
        """Firing sequences of a single-return packet (24 on the VLP-16)."""
        return self.blocks_per_packet * self.sequences_per_block

    def columns_per_packet(self, mode: str) -> int:
        """Frame columns (firing sequences) one packet carries in return mode ``mode``: 24, or 12 in dual."""
        return self.sequences_per_packet // (2 if mode == "dual" else 1)

    def packet_period_ns(self, mode: str) -> int:
        """Time between consecutive data packets in return mode ``mode``, ns (1 327 104, dual 663 552)."""
        return self.columns_per_packet(mode) * self.sequence_ns

    def packet_period_us(self, mode: str) -> float:
        """:meth:`packet_period_ns` in µs (1327.104, dual 663.552)."""
        return self.packet_period_ns(mode) / 1000.0

    def columns_per_rotation(self, frequency_hz: float | None) -> int:
        """Firing sequences of one rotation at ``frequency_hz`` (1808 at 10 Hz; 10 Hz when unknown)."""
        return int(round(1e9 / ((frequency_hz or 10.0) * self.sequence_ns)))


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

#: Every model lidarpkt decodes.
MODELS: tuple[VelodyneModel, ...] = (VLP16,)


def model_for_product(product_id: int) -> VelodyneModel | None:
    """The model whose packets carry ``product_id`` (0x21 gives the VLP-16: detection tells an
    HDL-32E apart by its timing), ``None`` for a model not in :data:`MODELS`."""
    for model in MODELS:
        if product_id in model.product_ids:
            return model
    return None


def model_named(name: str) -> VelodyneModel:
    """The model called ``name`` (``"VLP-16"``). Raises :class:`~lidarpkt.errors.UnknownSensorError` if unknown."""
    for model in MODELS:
        if model.name == name:
            return model
    raise UnknownSensorError(f"unknown Velodyne model {name!r}; lidarpkt decodes {', '.join(m.name for m in MODELS)}")
