"""The Hesai Pandar models lidarpkt decodes, as data: one frozen :class:`HesaiModel` per model.

A model is a row of :data:`MODELS`: its packet layout (:mod:`lidarpkt.vendors.hesai.packet`), the payload
sizes it sends, what its header says (protocol version, lasers, blocks), its distance unit, the
year its UTC field counts from, its firing timing (:mod:`lidarpkt.vendors.hesai.timing`) and its range
limits. Detection (:mod:`lidarpkt.vendors.hesai.detect`), decoding, frames, the encoder and ``info`` read
their facts here.

Return modes (:data:`RETURN_MODES`): the tail's return-mode byte names the returns of a firing, in
block order. Each return is a labelled slot of the frame (slot r = block r of each firing group).
The dual mark rule (Hesai user manuals, "Dual Return"): in Last+Strongest (0x39) and
First+Strongest (0x3C) the second block holds the strongest return, unless that return is already in
the first block (the last or the first return was also the strongest); then it holds the second
strongest. lidarpkt marks such pixels in ``frame.extra["second_strongest"]``: the second block's
reflectivity is lower than the first's (the sensor's own measure of strength; equal returns, the
same echo sent twice, are not marked). The same rule holds for every model here.
First+Last (0x3B): on the PandarXT16 and XT32 the first block holds the *last* return and the second
the first (:attr:`HesaiModel.first_last_swapped`; nebula swaps them for these two models too).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidarpkt.errors import UnknownSensorError
from . import packet as P

#: return-mode byte → labels of its return slots, in block order
RETURN_MODES: dict[int, tuple[str, ...]] = {
    0x33: ("first",),
    0x34: ("second",),
    0x37: ("strongest",),
    0x38: ("last",),
    0x39: ("last", "strongest"),
    0x3A: ("first", "second"),
    0x3B: ("first", "last"),
    0x3C: ("first", "strongest"),
    0x3D: ("first", "last", "strongest"),
    0x3E: ("strongest", "second_strongest"),
}
#: return-mode byte → its name in ``SensorInfo.return_mode`` and ``lidarpkt info``
RETURN_MODE_NAMES: dict[int, str] = {
    0x33: "first", 0x34: "second", 0x37: "strongest", 0x38: "last", 0x39: "last_strongest",
    0x3A: "first_second", 0x3B: "first_last", 0x3C: "first_strongest", 0x3D: "first_last_strongest",
    0x3E: "strongest_second_strongest",
}
#: modes whose second slot holds the second strongest return where the first already is the strongest
MARKED_MODES = frozenset({0x39, 0x3C})


@dataclass(frozen=True)
class HesaiModel:
    """What lidarpkt needs to know about one Pandar model.

    Attributes:
        name: ``"PandarXT32"``.
        layout: the packet's NumPy dtype (:mod:`lidarpkt.vendors.hesai.packet`).
        sizes: the UDP payload sizes it sends (the first is what the encoder writes); bytes past the
            layout are optional fields lidarpkt does not read.
        channels: lasers (units per block).
        blocks: data blocks per packet.
        protocol: ``(major, minor)`` of the 12-byte header; ``None`` for models without one.
        dis_unit_mm: the distance unit where the packet does not say it (Pandar40P: 4 mm), else ``None``.
        year_offset: the UTC year byte counts from this year (1900 or 2000).
        returns: the return counts its modes have (1, 2; the XT32M also 3).
        first_last_swapped: in First+Last mode the first block holds the last return.
        timing: key of its firing-time tables (:func:`lidarpkt.vendors.hesai.timing.firing_offsets_ns`).
        min_range_m, max_range_m: the range the manual specifies (nebula's limits for the model).
        grid_resolution_deg: azimuth between firings at 10 Hz, degrees.
    """

    name: str
    layout: np.dtype
    sizes: tuple[int, ...]
    channels: int
    blocks: int
    protocol: tuple[int, int] | None
    dis_unit_mm: int | None
    year_offset: int
    returns: tuple[int, ...]
    first_last_swapped: bool
    timing: str
    min_range_m: float
    max_range_m: float
    grid_resolution_deg: float
    header: str = field(default="12B")

    def __post_init__(self) -> None:
        if self.layout.itemsize != min(self.sizes):
            raise ValueError(f"{self.name}: layout of {self.layout.itemsize} B, packets of {self.sizes} B")

    def labels(self, mode: int) -> tuple[str, ...]:
        """Labels of the return slots in return mode ``mode`` (its byte)."""
        labels = RETURN_MODES[mode]
        if mode == 0x3B and self.first_last_swapped:
            return ("last", "first")
        return labels

    def columns_per_packet(self, n_returns: int) -> int:
        return self.blocks // n_returns


def _row(name, *, header, unit, channels, blocks, tail, sizes, protocol, dis_unit_mm=None, year_offset=1900,
         returns=(1, 2), swapped=False, timing, min_range_m, max_range_m, grid, sob=False, body_crc=False,
         safety=None) -> HesaiModel:
    hdr = {"12B": P.HEADER_12B, "8B": P.HEADER_8B, None: None}[header]
    layout = P.packet_dtype(header=hdr, unit=unit, channels=channels, blocks=blocks, tail=tail, sob=sob,
                            body_crc=body_crc, safety=safety, trailing_bytes=min(sizes) - _size(
                                hdr, unit, channels, blocks, tail, sob, body_crc, safety))
    return HesaiModel(name, layout, sizes, channels, blocks, protocol, dis_unit_mm, year_offset, tuple(returns),
                      swapped, timing, min_range_m, max_range_m, grid, header=header or "none")


def _size(hdr, unit, channels, blocks, tail, sob, body_crc, safety) -> int:
    return P.packet_dtype(header=hdr, unit=unit, channels=channels, blocks=blocks, tail=tail, sob=sob,
                          body_crc=body_crc, safety=safety).itemsize


PANDAR40P = _row("Pandar40P", header=None, unit=P.UNIT_3B, channels=40, blocks=10, tail=P.TAIL_40P, sob=True,
                 sizes=(1262, 1266), protocol=None, dis_unit_mm=4, year_offset=2000, timing="p40",
                 min_range_m=0.3, max_range_m=200.0, grid=0.2)
# Pandar64: the tail of the 40P, after an 8-byte header. Its UTC year byte counts from 1900: the
# unit in the bag here sends 120 (2020; from 2000 it would be 2120), unlike the 40P's 17 (2017).
PANDAR64 = _row("Pandar64", header="8B", unit=P.UNIT_3B, channels=64, blocks=6, tail=P.TAIL_40P,
                sizes=(1194, 1198), protocol=None, year_offset=1900, timing="p64",
                min_range_m=0.3, max_range_m=200.0, grid=0.2)
PANDARQT64 = _row("PandarQT64", header="12B", unit=P.UNIT_4B, channels=64, blocks=4, tail=P.TAIL_QT64,
                  sizes=(1072,), protocol=(3, 1), timing="qt64", min_range_m=0.1, max_range_m=60.0, grid=0.6)
PANDARQT128 = _row("PandarQT128", header="12B", unit=P.UNIT_4B, channels=128, blocks=2, tail=P.TAIL_QT128,
                   sizes=(1127,), protocol=(3, 2), timing="qt128", min_range_m=0.05, max_range_m=50.0, grid=0.4,
                   body_crc=True, safety=P.FUNCTIONAL_SAFETY_QT128)
PANDARXT16 = _row("PandarXT16", header="12B", unit=P.UNIT_4B, channels=16, blocks=8, tail=P.TAIL_XT,
                  sizes=(568,), protocol=(6, 1), swapped=True, timing="xt16", min_range_m=0.05, max_range_m=120.0,
                  grid=0.18)
PANDARXT32 = _row("PandarXT32", header="12B", unit=P.UNIT_4B, channels=32, blocks=8, tail=P.TAIL_XT,
                  sizes=(1080,), protocol=(6, 1), swapped=True, timing="xt32", min_range_m=0.05, max_range_m=120.0,
                  grid=0.18)
PANDARXT32M = _row("PandarXT32M", header="12B", unit=P.UNIT_4B, channels=32, blocks=6, tail=P.TAIL_XT,
                   sizes=(820,), protocol=(6, 1), returns=(1, 2, 3), timing="xt32m", min_range_m=0.5,
                   max_range_m=300.0, grid=0.18)

#: Every model lidarpkt decodes.
MODELS: tuple[HesaiModel, ...] = (PANDAR40P, PANDAR64, PANDARQT64, PANDARQT128, PANDARXT16, PANDARXT32, PANDARXT32M)
#: payload size → the models that send it
BY_SIZE: dict[int, tuple[HesaiModel, ...]] = {}
for _m in MODELS:
    for _s in _m.sizes:
        BY_SIZE[_s] = BY_SIZE.get(_s, ()) + (_m,)


def model_named(name: str) -> HesaiModel:
    """The model called ``name`` (``"PandarXT32"``, case-insensitive, ``"Pandar"`` optional).

    Raises :class:`~lidarpkt.errors.UnknownSensorError` for a model not in :data:`MODELS`."""
    key = name.lower().replace("pandar", "").replace("-", "")
    for model in MODELS:
        if model.name.lower().replace("pandar", "") == key:
            return model
    raise UnknownSensorError(f"unknown Hesai model {name!r}; lidarpkt decodes {', '.join(m.name for m in MODELS)}")
