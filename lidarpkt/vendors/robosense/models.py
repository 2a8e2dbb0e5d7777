"""The RoboSense models lidarpkt decodes, as data: one frozen :class:`RobosenseModel` per model.

A model is a row of :data:`MODELS`: its MSOP and DIFOP layouts (:mod:`lidarpkt.vendors.robosense.packet`),
lasers, blocks and slots per block, how a block's slots map to lasers, firings and returns, its
distance unit, firing timing (:mod:`lidarpkt.vendors.robosense.timing`), lens centre, the DIFOP's
return-mode bytes and what tells it apart in the MSOP header. Detection, decoding, frames, XYZ, the
encoder and ``info`` read their facts here.

Slots. A block has ``channels`` slots; slot ``s`` is laser ``s % lasers``. With two firings per block
(RS-LiDAR-16, RS-Helios-16P) slots 0-15 are the first firing sequence of the 16 lasers and 16-31 the
second in single return, and the two returns of one sequence in dual return (each manual's "MSOP
packet definition"). The other models fire every laser once per block; in dual return blocks 2k and
2k+1 hold the two returns of one sequence (RS-LiDAR-32, RS-Bpearl, RS-Helios), or each block says
which return it holds in its ``ret_id`` (RS-Ruby, RS-Ruby Plus).

Return slot labels (the sensor's definitions): single return as the DIFOP's return-mode byte says
(``strongest``, ``last``, ``first``); dual: RS-Bpearl ``strongest``, ``second_strongest`` (its manual,
Appendix A.2); RS-Ruby Plus ``last``, ``strongest`` (its manual, "Data Blocks"); RS-Ruby the same; the
RS-LiDAR-16/32 and the Helios family ``strongest``, ``last`` (the order of nebula's reading of the
Helios manual). Without a DIFOP the single-return label is ``unknown``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarpkt.errors import UnknownSensorError
from . import packet as P

_HELIOS_MODES = {0x00: ("strongest", "last"), 0x04: ("strongest",), 0x05: ("last",), 0x06: ("first",)}
_V1_MODES = {0x00: ("strongest", "last"), 0x01: ("strongest",), 0x02: ("last",)}
_BPEARL_MODES = {0x00: ("strongest", "second_strongest"), 0x01: ("strongest",), 0x02: ("last",)}
_RUBY_MODES = {0x03: ("last", "strongest"), 0x01: ("last",), 0x02: ("strongest",)}


@dataclass(frozen=True, eq=False)  # a model is its row: compared and hashed by identity
class RobosenseModel:
    """What lidarpkt needs to know about one RoboSense model.

    Attributes:
        name: ``"RS-Helios"``.
        family: header layout, ``"v1"`` (8-byte id), ``"helios"`` or ``"ruby"`` (4-byte id).
        layout: the MSOP dtype; difop_layout: the DIFOP dtype.
        lasers: lasers (frame rows); blocks: blocks per packet; channels: slots per block.
        firings_per_block: firing sequences a block holds in single return (2 or 1).
        dual_layout: ``"in_block"``, ``"block_pairs"`` or ``"ret_id"`` (see the module docstring).
        distance_unit_um: µm per distance unit, ``None`` where the header's ``range_resolution`` says.
        block_period_ns: time between blocks in single return (between block pairs in dual return).
        dual_block_period_ns: time between blocks in dual return where a block holds both returns of a
            sequence (RS-LiDAR-16: one sequence, 55.5 µs; RS-Helios-16P: 55.56 µs as in single return).
        timing: key of its firing table (:data:`lidarpkt.vendors.robosense.timing.TABLES`).
        lens_rx_m, lens_rz_m: the lens centre: a beam starts ``lens_rx_m`` out along the firing's
            azimuth and ``lens_rz_m`` up (rs_driver's RX and RZ).
        return_modes: the DIFOP's return-mode byte → labels of the return slots.
        difop_angle_unit_mdeg: thousandths of a degree per unit of the DIFOP's angles (RS-LiDAR-32: 1;
            RS-LiDAR-16: 0.1 for its 24-bit pitches; the others 10).
        codes: MSOP header values that name this model: alternatives, each a tuple of (field, value) pairs
            that must all hold (the Helios and Ruby families' ``lidar_type``/``lidar_model`` as
            :func:`lidarpkt.vendors.robosense.detect.type_and_model` reads them).
        packet_counter: the header field that counts packets (+1 each), ``None`` if it has none.
        min_range_m, max_range_m: the range rs_driver accepts for the model (for ``info``).
    """

    name: str
    family: str
    layout: np.dtype
    difop_layout: np.dtype
    lasers: int
    blocks: int
    channels: int
    firings_per_block: int
    dual_layout: str
    distance_unit_um: int | None
    block_period_ns: int
    dual_block_period_ns: int
    timing: str
    lens_rx_m: float
    lens_rz_m: float
    return_modes: dict[int, tuple[str, ...]]
    difop_angle_unit_mdeg: float
    codes: tuple[tuple[tuple[str, int], ...], ...]
    packet_counter: str | None
    min_range_m: float
    max_range_m: float

    def __post_init__(self) -> None:
        if self.layout["blocks"].shape != (self.blocks,) or self.layout["blocks"].base["channels"].shape != (self.channels,):
            raise ImportError(f"{self.name}: layout does not have {self.blocks} blocks of {self.channels} slots")
        if self.channels != self.lasers * self.firings_per_block:
            raise ImportError(f"{self.name}: {self.channels} slots are not {self.firings_per_block} firings of {self.lasers}")

    def labels(self, mode: int | None, n_returns: int) -> tuple[str, ...]:
        """Labels of the return slots for the DIFOP's return-mode byte ``mode`` (``None``: no DIFOP)
        with ``n_returns`` returns per firing."""
        labels = self.return_modes.get(mode) if mode is not None else None
        if labels is not None and len(labels) == n_returns:
            return labels
        if n_returns == 2:
            return next(v for v in self.return_modes.values() if len(v) == 2)
        return ("unknown",)

    def dual_mode(self) -> int:
        """The DIFOP return-mode byte of dual return."""
        return next(k for k, v in self.return_modes.items() if len(v) == 2)

    def columns_per_block(self, n_returns: int) -> int:
        """Firing sequences (frame columns) per block; in block-pair dual return ½ (returned as 0)."""
        if n_returns == 1:
            return self.firings_per_block
        return 1 if self.dual_layout in ("in_block", "ret_id") else 0

    def group_period_ns(self, n_returns: int) -> int:
        """Time between consecutive block groups: blocks, or the block pairs of block-pair dual return."""
        if n_returns == 2 and self.dual_layout == "in_block":
            return self.dual_block_period_ns
        return self.block_period_ns

    def column_period_ns(self, n_returns: int) -> float:
        """Time between consecutive firing sequences (columns)."""
        if n_returns == 1:
            return self.block_period_ns / self.firings_per_block
        return float(self.group_period_ns(n_returns))

    def grid_resolution_deg(self, rotation_hz: float = 10.0) -> float:
        """Azimuth between firing sequences at ``rotation_hz``, single return."""
        return round(360.0 * rotation_hz * self.column_period_ns(1) * 1e-9, 3)


def _row(name: str, family: str, *, lasers: int, firings: int = 1, dual: str, unit_um: int | None, period_ns: int,
         dual_period_ns: int | None = None, timing: str, rx: float, rz: float = 0.0, modes: dict, codes: tuple, counter: str | None = None,
         angle_unit: float = 10.0, ranges: tuple[float, float], layout: np.dtype | None = None,
         difop: np.dtype | None = None) -> RobosenseModel:
    if layout is None:
        layout = {"v1": P.MSOP_V1_YMD, "helios": P.MSOP_HELIOS, "ruby": P.MSOP_RUBY}[family]
    if difop is None:
        difop = {"v1": P.DIFOP_V1_32, "helios": P.DIFOP_HELIOS, "ruby": P.DIFOP_RUBY}[family]
    blocks, channels = layout["blocks"].shape[0], layout["blocks"].base["channels"].shape[0]
    return RobosenseModel(name, family, layout, difop, lasers, blocks, channels, firings, dual, unit_um, period_ns,
                          period_ns if dual_period_ns is None else dual_period_ns, timing, rx, rz, modes, angle_unit, codes, counter, *ranges)


RS_LIDAR_16 = _row("RS-LiDAR-16", "v1", lasers=16, firings=2, dual="in_block", unit_um=5000, period_ns=111000,
                   dual_period_ns=55500,
                   timing="rs16", rx=0.03825, modes=_V1_MODES, codes=((("lidar_model_flag", 0x01),),),
                   angle_unit=0.1, ranges=(0.4, 230.0), difop=P.DIFOP_RS16)
RS_LIDAR_32 = _row("RS-LiDAR-32", "v1", lasers=32, dual="block_pairs", unit_um=5000, period_ns=55520, timing="rs32",
                   rx=0.03997, modes=_V1_MODES, codes=((("lidar_model_flag", 0x02),),), angle_unit=1.0,
                   ranges=(0.4, 230.0))
RS_BPEARL = _row("RS-Bpearl", "v1", lasers=32, dual="block_pairs", unit_um=5000, period_ns=55520, timing="bpearl",
                 rx=0.01473, rz=0.09427, modes=_BPEARL_MODES, codes=((("lidar_model_flag", 0x03),),),
                 counter="packet_count", ranges=(0.1, 150.0))
RS_BPEARL_V4 = _row("RS-Bpearl-V4", "v1", lasers=32, dual="block_pairs", unit_um=2500, period_ns=55560,
                    timing="bpearl_v4", rx=0.01619, rz=0.09571, modes=_BPEARL_MODES, codes=((("lidar_type", 0x03), ("lidar_model", 0x04)),),
                    counter="packet_count", ranges=(0.1, 150.0), layout=P.MSOP_V1_UTC)
RS_HELIOS = _row("RS-Helios", "helios", lasers=32, dual="block_pairs", unit_um=None, period_ns=55560, timing="helios",
                 rx=0.03498, modes=_HELIOS_MODES, codes=((("lidar_model", 0x01),), (("lidar_model", 0x02),),
                                                        (("lidar_model", 0x04),)),
                 counter="bottom_board_packet_count", ranges=(0.1, 180.0))
RS_HELIOS_16P = _row("RS-Helios-16P", "helios", lasers=16, firings=2, dual="in_block", unit_um=None, period_ns=55560,
                     timing="helios", rx=0.03498, modes=_HELIOS_MODES, codes=((("lidar_model", 0x03),),),
                     counter="bottom_board_packet_count", ranges=(0.1, 180.0))
RS_RUBY = _row("RS-Ruby", "ruby", lasers=128, dual="ret_id", unit_um=5000, period_ns=55550, timing="ruby", rx=0.03615,
               modes=_RUBY_MODES, codes=((("lidar_type", 0x04),),), ranges=(0.4, 250.0))
RS_RUBY_PLUS = _row("RS-Ruby-Plus", "ruby", lasers=128, dual="ret_id", unit_um=5000, period_ns=55560,
                    timing="ruby_plus", rx=0.02892, modes=_RUBY_MODES, codes=((("lidar_type", 0x05),),),
                    ranges=(0.4, 250.0))

#: Every model lidarpkt decodes.
MODELS: tuple[RobosenseModel, ...] = (RS_LIDAR_16, RS_LIDAR_32, RS_BPEARL, RS_BPEARL_V4, RS_HELIOS, RS_HELIOS_16P,
                                      RS_RUBY, RS_RUBY_PLUS)
#: family → its models, the default (the one taken when the header names none) first
FAMILIES: dict[str, tuple[RobosenseModel, ...]] = {
    "v1": (RS_LIDAR_32, RS_LIDAR_16, RS_BPEARL_V4, RS_BPEARL),
    "helios": (RS_HELIOS, RS_HELIOS_16P),
    "ruby": (RS_RUBY, RS_RUBY_PLUS),
}
#: rotation rates the sensors offer, rpm
ROTATION_RPM = (300, 600, 1200)
_ALIASES = {"helios16p": "rs-helios-16p", "rshelios16p": "rs-helios-16p", "helios": "rs-helios",
            "rshelios": "rs-helios", "helios5515": "rs-helios", "helios1615": "rs-helios", "helios1610": "rs-helios",
            "rs16": "rs-lidar-16", "rs32": "rs-lidar-32", "rsbp": "rs-bpearl", "bpearl": "rs-bpearl",
            "rs128": "rs-ruby", "ruby": "rs-ruby", "rsp128": "rs-ruby-plus", "rubyplus": "rs-ruby-plus"}


def _key(name: str) -> str:
    return "".join(ch for ch in name.lower() if ch.isalnum())


def model_named(name: str) -> RobosenseModel:
    """The model called ``name`` (``"RS-Helios-16P"``, case, dashes and the ``RS-`` prefix optional;
    rs_driver's and nebula's names too: ``RSHELIOS_16P``, ``RobosenseHelios16P``).

    Raises :class:`~lidarpkt.errors.UnknownSensorError` for a model not in :data:`MODELS`."""
    key = _key(name).removeprefix("robosense")
    key = _key(_ALIASES.get(key, key))
    for model in MODELS:
        if _key(model.name) in (key, "rs" + key):
            return model
    raise UnknownSensorError(f"unknown RoboSense model {name!r}; lidarpkt decodes {', '.join(m.name for m in MODELS)}")
