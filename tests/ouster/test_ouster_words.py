"""Every Ouster profile word by word: the decoder's fields against bits pulled out of the raw packets
with Python ints, at the positions the manual gives (not lidarpkt's tables).

The layouts below are written out from /work/shared/REFERENCE.md (the firmware user manual's
"Lidar Data Format" tables) and, for the FUSA profile of firmware 3.1 (not in REFERENCE.md), from
the manual's table as ouster-sdk 1.0.1 declares it (``ouster_core/src/parsing.cpp``:
``DUAL_LB_FIELD_INFO`` and the FUSA header offsets). A field is ``(bit offset from the record's
first byte, width, up-shift)``; a record is read as one little-endian integer.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_ouster_cases import CAPTURES, lidar_streams

from lidarpkt.vendors.ouster import decode_packets

# ------------------------------------------------------------------ the manual's layouts
PIXEL = {
    "LEGACY": (12, {"RANGE": (0, 20, 0), "FLAGS": (28, 4, 0), "REFLECTIVITY": (32, 8, 0), "SIGNAL": (48, 16, 0),
                    "NEAR_IR": (64, 16, 0)}),
    "RNG19_RFL8_SIG16_NIR16": (12, {"RANGE": (0, 19, 0), "FLAGS": (19, 5, 0), "REFLECTIVITY": (32, 8, 0),
                                    "SIGNAL": (48, 16, 0), "NEAR_IR": (64, 16, 0)}),
    "RNG19_RFL8_SIG16_NIR16_DUAL": (16, {"RANGE": (0, 19, 0), "FLAGS": (19, 5, 0), "REFLECTIVITY": (24, 8, 0),
                                         "RANGE2": (32, 19, 0), "FLAGS2": (51, 5, 0), "REFLECTIVITY2": (56, 8, 0),
                                         "SIGNAL": (64, 16, 0), "SIGNAL2": (80, 16, 0), "NEAR_IR": (96, 16, 0)}),
    "RNG15_RFL8_NIR8": (4, {"RANGE": (0, 15, 3), "FLAGS": (15, 1, 0), "REFLECTIVITY": (16, 8, 0),
                            "NEAR_IR": (24, 8, 4)}),
    "FUSA_RNG15_RFL8_NIR8_DUAL": (8, {"RANGE": (0, 15, 3), "FLAGS": (15, 1, 0), "REFLECTIVITY": (16, 8, 0),
                                      "NEAR_IR": (24, 8, 4), "RANGE2": (32, 15, 3), "FLAGS2": (47, 1, 0),
                                      "REFLECTIVITY2": (48, 8, 0), "WINDOW": (56, 8, 0)}),
}
STANDARD_HEADER = {"packet_type": (0, 16), "frame_id": (16, 16), "init_id": (32, 24), "prod_sn": (56, 40),
                   "alert_flags": (96, 8), "countdown_thermal_shutdown": (128, 8),
                   "countdown_shot_limiting": (136, 8), "thermal_shutdown": (144, 4), "shot_limiting": (152, 4)}
FUSA_HEADER = {"packet_type": (0, 8), "init_id": (8, 24), "frame_id": (32, 32), "alert_flags": (64, 8),
               "prod_sn": (88, 40), "countdown_thermal_shutdown": (128, 8), "countdown_shot_limiting": (136, 8),
               "thermal_shutdown": (144, 4), "shot_limiting": (152, 4)}


def bits(record: bytes, offset: int, width: int, upshift: int = 0) -> int:
    return ((int.from_bytes(record, "little") >> offset) & ((1 << width) - 1)) << upshift


def u(record: bytes, start: int, size: int) -> int:
    return int.from_bytes(record[start : start + size], "little")


CASES = [(p, j) for p, j, _ in CAPTURES if "empty" not in p]


@pytest.mark.parametrize("pcap,jsons", CASES, ids=[p.split("/")[-1] for p, _ in CASES])
def test_every_word_at_the_manuals_bit_positions(pcap, jsons):
    checked = {}
    for md, batch in lidar_streams(pcap, jsons):
        name = md.profile.name
        pixel_bytes, pixel_fields = PIXEL[name]
        legacy = name == "LEGACY"
        H, C = md.pixels_per_column, md.columns_per_packet
        col_header = 16 if legacy else 12
        col_bytes = col_header + H * pixel_bytes + (4 if legacy else 0)
        head = 0 if legacy else 32
        assert batch.payload_size == head + C * col_bytes + (0 if legacy else 32)
        f = decode_packets(batch.payload, md)
        n = len(batch)
        for i in range(n):  # every packet's header and column headers
            pkt = bytes(batch.payload[i])
            if not legacy:
                layout = FUSA_HEADER if name.startswith("FUSA") else STANDARD_HEADER
                for field, (off, width) in layout.items():
                    assert int(f.header[field][i]) == bits(pkt[:32], off, width), (i, field)
                assert np.array_equal(f.footer[i], np.frombuffer(pkt[-32:], np.uint8))
            for c in range(C):
                col = pkt[head + c * col_bytes : head + (c + 1) * col_bytes]
                assert int(f.timestamp_ns[i, c]) == u(col, 0, 8)
                assert int(f.measurement_id[i, c]) == u(col, 8, 2)
                if legacy:
                    assert int(f.column_frame_id[i, c]) == u(col, 10, 2)
                    assert int(f.encoder_count[i, c]) == u(col, 12, 4)
                    assert int(f.status[i, c]) == u(col, col_bytes - 4, 4)
                else:
                    assert int(f.status[i, c]) == u(col, 10, 2)
        sample = range(n) if H <= 64 else sorted({0, n // 2, n - 1})  # every pixel (of 3 packets at 128 rows)
        for i in sample:
            pkt = bytes(batch.payload[i])
            for c in range(C):
                base = head + c * col_bytes + col_header
                for h in range(H):
                    px = pkt[base + h * pixel_bytes : base + (h + 1) * pixel_bytes]
                    for field, (off, width, up) in pixel_fields.items():
                        want = bits(px, off, width, up)
                        assert int(f.pixels[field][i, c, h]) == want, (i, c, h, field)
                        if n > 1:  # single-packet captures may hold no second return
                            checked[(name, field)] = checked.get((name, field), 0) + (want != 0)
    # each measured field was non-zero somewhere (else a wrong position could read zeros and agree)
    zero = {k for k, v in checked.items() if v == 0 and k[1] not in ("FLAGS", "FLAGS2", "WINDOW")}
    assert not zero, f"fields never non-zero in {pcap}: {sorted(zero)}"


def test_fusa_dual_second_return_is_checked_on_real_data():
    """same_ports_nonlegacy.pcap holds the one FUSA packet: its RANGE2 words are non-zero and in 8 mm steps."""
    streams = lidar_streams("ouster-sdk/same_ports_nonlegacy.pcap",
                            ["ouster-sdk/same_ports_nonlegacy.1.json", "ouster-sdk/same_ports_nonlegacy.2.json"])
    (md, batch), = [(m, b) for m, b in streams if m.profile.name == "FUSA_RNG15_RFL8_NIR8_DUAL"]
    f = decode_packets(batch.payload, md)
    for name in ("RANGE", "REFLECTIVITY", "NEAR_IR", "RANGE2", "REFLECTIVITY2"):
        assert np.count_nonzero(f.pixels[name]) > 0, name
    r2 = f.pixels["RANGE2"]
    assert np.count_nonzero(r2) == 26 and np.all(r2 % 8 == 0)
    word = batch.payload[0, 32 + 12 + 4 : 32 + 12 + 8].view("<u4")[0]  # column 0, pixel 0, second word
    assert int(r2[0, 0, 0]) == (int(word) & 0x7FFF) * 8
    # FUSA header: 8-bit packet type then a 24-bit init_id in the first 32-bit word
    first = int(batch.payload[0, :4].view("<u4")[0])
    assert int(f.header["init_id"][0]) == first >> 8 == md.init_id
