"""Hostile copies of the Pandar bags' packets: damaged bytes, wrong sizes, impossible fields, a damaged
PandarScan. Each gives counted skips (the decoder's stats, ``lidarpkt.core.dropped``) or one clear
``lidarpkt.errors`` exception, never another exception."""

from __future__ import annotations

import glob
import warnings

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import CaptureFormatError, LidarpktError, SkippedPacketWarning
from lidarpkt.vendors.hesai import HesaiCalibration, HesaiDecoder, detect_model
from lidarpkt.vendors.hesai.models import MODELS
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.bags import BagReader
from lidarpkt.vendors.registry import ros_definitions
from lidarpkt.vendors.registry import bag_messages

FOLDERS = ["40p", "64", "qt64", "qt128", "xt16", "xt32", "xt32m"]


def _bag_batch(ext, folder) -> PacketBatch:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return next(iter(BagReader(glob.glob(str(ext(f"nebula/hesai/{folder}")) + "/*/")[0], messages=bag_messages()).batches()))


def _decoder(model):
    cal = HesaiCalibration(np.linspace(15, -25, model.channels), np.zeros(model.channels), "test")
    return HesaiDecoder(model=model, calibration=cal)


def _accounted(dec, n):
    st = dec.stats
    return st.packets == n and st.decoded_packets + st.malformed + st.duplicate_packets + st.late_packets == n


@pytest.mark.parametrize("folder", FOLDERS)
def test_damaged_bytes_are_counted_never_a_crash(ext, folder):
    batch = _bag_batch(ext, folder)
    model = detect_model(batch.payload)
    rng = np.random.default_rng(FOLDERS.index(folder))
    for _ in range(6):
        payload = batch.payload.copy()
        hit = rng.random(len(payload)) < 0.2
        rows = np.flatnonzero(hit)
        cols = rng.integers(0, payload.shape[1], (rows.size, 8))
        payload[rows[:, None], cols] = rng.integers(0, 256, cols.shape, dtype=np.uint8)
        dec = _decoder(model)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a RuntimeWarning (overflow) would be a bug
            warnings.simplefilter("ignore", SkippedPacketWarning)
            frames = []
            for part in np.array_split(np.arange(len(payload)), 3):
                frames += dec.push(PacketBatch.from_payloads(payload[part], batch.timestamp_ns[part], first_index=int(part[0])))
            frames += dec.finish()
        assert _accounted(dec, len(payload))
        for f in frames:
            assert f.range_mm.shape[1] == model.channels and np.isfinite(f.xyz()).all()


def test_impossible_fields_are_counted_exactly(ext):
    batch = _bag_batch(ext, "xt32")
    model = detect_model(batch.payload)
    payload = batch.payload.copy()
    payload[10, 1052 + 10] = 0x99  # return mode byte: no such mode
    payload[20, 12] = 0xFF  # block 0 azimuth 0x??FF ... made ≥ 360°:
    payload[20, 13] = 0xFF
    payload[30, 0] = 0x00  # start of packet
    payload[40, 1052 + 13 + 1] = 13  # UTC month 13
    dec = _decoder(model)
    with pytest.warns(SkippedPacketWarning, match="skipped 4 PandarXT32 packets"):
        dec.push(PacketBatch.from_payloads(payload, batch.timestamp_ns))
    assert dec.stats.malformed_fields == 4 and dec.stats.decoded_packets == len(payload) - 4


def test_wrong_size_and_unknown_streams_are_skipped_and_said(ext):
    batch = _bag_batch(ext, "qt64")
    model = detect_model(batch.payload)
    dec = _decoder(model)
    with pytest.warns(SkippedPacketWarning, match="1000 B"):
        assert dec.push(PacketBatch.from_payloads(batch.payload[:5, :1000], batch.timestamp_ns[:5])) == []
    assert dec.stats.malformed_size == 5
    auto = HesaiDecoder()
    with pytest.warns(SkippedPacketWarning, match="no Pandar packets"):
        auto.push(PacketBatch.from_payloads(np.zeros((3, 1080), np.uint8), np.zeros(3, np.int64)))
    assert auto.stats.malformed_size == 3 and auto.model is None


def test_duplicates_and_late_packets_are_dropped_and_counted(ext):
    batch = _bag_batch(ext, "xt32")
    model = detect_model(batch.payload)
    dec = _decoder(model)
    dec.push(batch.select(np.arange(100, 200)))
    again = np.r_[np.arange(150, 160), np.arange(200, 250), np.arange(240, 245)]  # late, new, duplicates
    dec.push(batch.select(again))
    assert dec.stats.late_packets == 10 and dec.stats.duplicate_packets == 5
    assert dec.stats.decoded_packets == 150 and _accounted(dec, len(again) + 100)
    counts = {"late": 10, "duplicate": 5}

    # the decoder's stats under the reasons of lidarpkt.core.dropped: the vendor's drop reasons
    from lidarpkt.vendors import registry

    assert {k: v for k, v in registry.vendor("hesai").drops(dec.stats).items() if k in counts} == counts


def _write_bag(path, scans):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    for name, text in ros_definitions().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    Scan, Packet = store.types["pandar_msgs/msg/PandarScan"], store.types["pandar_msgs/msg/PandarPacket"]
    Time, Header = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    with Writer(path) as w:
        conn = w.add_connection("/pandar_packets", "pandar_msgs/msg/PandarScan", typestore=store)
        for k, (payload, sizes, times) in enumerate(scans):
            pk = []
            for p, s, t in zip(payload, sizes, times):
                data = np.zeros(1500, np.uint8)
                data[: len(p)] = p
                pk.append(Packet(stamp=Time(sec=int(t // 10**9), nanosec=int(t % 10**9)), data=data, size=int(s)))
            msg = Scan(header=Header(stamp=Time(sec=k, nanosec=0), frame_id="hesai"), packets=pk)
            w.write(conn, int(times[-1]), store.serialize_cdr(msg, "pandar_msgs/msg/PandarScan"))


def test_damaged_packets_in_a_bag_are_reported_by_lidarpkt_dropped(ext, tmp_path):
    batch = _bag_batch(ext, "xt32")
    payload = batch.payload.copy()
    payload[::50, 0] = 0  # 10 packets without their start bytes
    _write_bag(tmp_path / "bag", [(payload, [1080] * len(payload), batch.timestamp_ns)])
    with pytest.warns(lidarpkt.errors.DroppedPacketsWarning, match="10 skipped as malformed"), \
            lidarpkt.open(tmp_path / "bag") as reader:
        frames = list(reader)
    assert frames and reader.stats.packets_of("hesai", "data") == 500
    assert reader.drop_counts().malformed == 10


def test_a_pandar_scan_of_two_sizes_or_an_oversized_packet_is_one_clear_error(ext, tmp_path):
    batch = _bag_batch(ext, "xt32")
    p, t = batch.payload[:4], batch.timestamp_ns[:4]
    _write_bag(tmp_path / "mixed", [(p, [1080, 1080, 1000, 1080], t)])
    with pytest.raises(CaptureFormatError, match="sizes"):
        list(lidarpkt.open(tmp_path / "mixed"))
    _write_bag(tmp_path / "big", [(p, [4000] * 4, t)])
    with pytest.raises(CaptureFormatError, match="1500-byte"):
        list(lidarpkt.open(tmp_path / "big"))


@pytest.mark.parametrize("model", MODELS, ids=[m.name for m in MODELS])
def test_random_bytes_of_every_size_never_crash(model):
    rng = np.random.default_rng(7)
    for size in model.sizes:
        payload = rng.integers(0, 256, (64, size), dtype=np.uint8)
        payload[::2, :2] = (0xEE, 0xFF) if model.header != "none" else (0xFF, 0xEE)
        for given in (model, None):
            dec = HesaiDecoder(model=given)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", SkippedPacketWarning)
                    dec.push(PacketBatch.from_payloads(payload, np.arange(64, dtype=np.int64)))
                    dec.finish()
            except LidarpktError:
                pass
            assert dec.stats.packets == 64


def test_a_udp_sequence_jump_claims_no_more_lost_packets_than_the_capture_time_holds(ext):
    """A sequence number moved 500,000 on (below the restart threshold) in a 0.1 s stretch of packets: the
    losses claimed are bounded by the capture time between the packets around it (lidarpkt.core.continuity)."""
    batch = _bag_batch(ext, "xt32")
    model = detect_model(batch.payload)
    layout = model.layout
    assert model is not None and "udp_sequence" in layout["tail"].names and layout.itemsize == batch.payload_size
    clean = _decoder(model)
    clean.push(batch)
    payload = batch.payload.copy()
    packets = payload.view(layout).reshape(-1)
    packets["tail"]["udp_sequence"][len(packets) // 2:] += 500_000  # every later packet agrees: a jump, not one bad packet
    hostile = _decoder(model)
    hostile.push(PacketBatch.from_payloads(payload, batch.timestamp_ns, first_index=0))
    from lidarpkt.core.continuity import CAPTURE_RESOLUTION_S
    from lidarpkt.vendors.hesai.decode import decode_packets

    span_ns = int(batch.timestamp_ns[-1] - batch.timestamp_ns[0])  # capture time of the whole batch
    period_ns = float(np.median(np.diff(decode_packets(batch.payload, model).timestamp_ns)))  # the sensor's
    # packets the capture time holds beyond those received, and the 20 ms a loss may borrow (bursty capture clocks)
    room = span_ns / period_ns - (len(batch) - 1) + CAPTURE_RESOLUTION_S * 1e9 / period_ns
    assert clean.stats.lost_packets == 0
    assert 0 <= hostile.stats.lost_packets <= max(room, 0) + 1
