"""Loss counts stay physical (issue 27): a packet whose time or frame id jumps further than the capture
time allows is counted as corrupted (its own reason) and skipped, the stream goes on, and no damage
makes the decoders or the live counters claim more lost packets than the capture time can hold."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import lidarpkt
from conftest import external
from lidarpkt.core.continuity import CAPTURE_RESOLUTION_S, StreamContinuity
from lidarpkt.errors import LidarpktError
from lidarpkt.vendors.ouster import load_metadata
from lidarpkt.vendors.ouster.stream import PacketCounter as OusterCounter
from lidarpkt.containers.pcap_reader import PcapReader
from lidarpkt.vendors.velodyne.models import VLP16
from lidarpkt.vendors.velodyne.stream import PacketCounter as VelodyneCounter

VLP = "veloview/vlp-16-test-90deg-1-50-frames.pcap"
OUSTER = "ouster-sdk/OS-1-32-G_v2.1.1_1024x10"  # LEGACY: the frame id is in the columns, no CRC to redo
OUSTER_PERIOD_NS = 1e9 / (10 * 1024 / 16)  # 1024 x 10, 16 columns per packet
VLP_PERIOD_NS = VLP16.packet_period_ns("strongest")


def _packets(path, size):
    return [p for p in PcapReader(path).packets() if len(p.payload) == size]


def _with_payload(data: bytes, old: bytes, new: bytes) -> bytes:
    at = data.find(old)
    assert at > 0 and data.find(old, at + 1) < 0
    return data[:at] + new + data[at + len(old):]


def _open(path, **kw):
    """(frames, decoder stats, dropped counts) of a whole read; warnings kept quiet."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with lidarpkt.open(path, **kw) as reader:
            frames = sum(1 for _ in reader)
            dec = max(reader.decoders.values(), key=lambda d: d.stats.packets)
            return frames, dec.stats, reader.drop_counts()


def _vlp_moved(tmp_path, k: int, by_us: int):
    src = external(VLP)
    pk = _packets(src, 1206)[k]
    moved = bytearray(pk.payload)
    ts = int.from_bytes(moved[1200:1204], "little")
    moved[1200:1204] = ((ts + by_us) % 3_600_000_000).to_bytes(4, "little")
    out = tmp_path / "moved.pcap"
    out.write_bytes(_with_payload(src.read_bytes(), pk.payload, bytes(moved)))
    return src, out


@pytest.mark.parametrize("by_us", [30 * 60 * 1_000_000, -30 * 60 * 1_000_000 + 1, 5_000_000])
@pytest.mark.parametrize("k", [0, 100, 1901])
def test_a_vlp16_packet_moved_in_time_is_corrupted_not_a_loss(tmp_path, k, by_us):
    """The issue's case: one packet's timestamp moved 30 minutes on made the read claim 1,354,857 lost
    packets of a 1,902-packet capture. Now it is one corrupted packet, skipped; the packets around it
    decode as before (its slot is empty: at most that one packet lost), the frames are the same."""
    src, moved = _vlp_moved(tmp_path, k, by_us)
    clean_frames, clean, _ = _open(src)
    frames, st, dropped = _open(moved)
    assert clean.lost_packets == 0 and clean.corrupted_packets == 0
    assert st.corrupted_packets == 1 and dropped.corrupted == 1
    assert st.lost_packets <= 1 and st.late_packets == st.out_of_order_packets == st.restarts == 0
    assert st.decoded_packets == clean.decoded_packets - 1
    # the capture's last frame is the 19 columns of its last packet after the wrap: gone with it
    assert frames == clean_frames - (k == 1901)


def test_the_live_counter_counts_the_moved_packet_as_corrupted():
    src = external(VLP)
    pk = _packets(src, 1206)
    payload = np.frombuffer(b"".join(p.payload for p in pk), np.uint8).reshape(len(pk), 1206).copy()
    host = np.array([p.timestamp_ns for p in pk], np.int64)
    ts = payload[100, 1200:1204].view("<u4")
    ts[0] = (int(ts[0]) + 1_800_000_000) % 3_600_000_000
    for with_host in (True, False):
        c = VelodyneCounter()
        for rows in np.array_split(np.arange(len(pk)), 7):
            c.update(payload[rows], host[rows] if with_host else None)
        assert (c.count.corrupted, c.count.interruptions, c.count.out_of_order) == (1, 0, 0)
        assert c.count.lost <= 1


def test_the_recorder_records_the_moved_packet_and_reports_it_corrupted(tmp_path):
    """The recorder's live path (PacketSink, as `lidarpkt record` feeds it, capture times included):
    every packet is recorded, the moved one is reported corrupted, no gap is claimed for it beyond its slot."""
    from lidarpkt.core.packet import PacketBatch
    from lidarpkt.writers.mcap.packets import PacketSink
    from lidarpkt.writers.mcap.writer import McapWriter

    src = external(VLP)
    pk = _packets(src, 1206)
    payload = np.frombuffer(b"".join(p.payload for p in pk), np.uint8).reshape(len(pk), 1206).copy()
    ts = payload[500, 1200:1204].view("<u4")
    ts[0] = (int(ts[0]) + 1_800_000_000) % 3_600_000_000
    host = np.array([p.timestamp_ns for p in pk], np.int64)
    writer = McapWriter(tmp_path / "rec.mcap")
    sink = PacketSink(writer)
    for rows in np.array_split(np.arange(len(pk)), 5):
        sink.push(PacketBatch(pk[0].src, pk[0].dst, host[rows], payload[rows], rows.astype(np.int64)))
    sink.finish()
    writer.close()
    (rep,) = sink.streams.values()
    assert rep.count.packets == len(pk) and rep.count.corrupted == 1 and sink.lost <= 1
    assert any("1 corrupted" in line for line in sink.report_lines())


def test_a_restarted_vlp16_clock_is_a_restart_nothing_lost_or_late(tmp_path):
    """Every packet from the 1000th on moved 20 minutes back (a sensor clock reset mid-capture): one
    restart, nothing lost, late or skipped, every packet decoded."""
    src = external(VLP)
    pk = _packets(src, 1206)
    data = bytearray(src.read_bytes())
    at = data.find(pk[1000].payload)
    for p in pk[1000:]:
        at = data.find(p.payload, at)
        ts = int.from_bytes(data[at + 1200:at + 1204], "little")
        data[at + 1200:at + 1204] = ((ts - 1_200_000_000) % 3_600_000_000).to_bytes(4, "little")
    out = tmp_path / "restart.pcap"
    out.write_bytes(bytes(data))
    _, st, dropped = _open(out)
    assert st.restarts == 1 and st.corrupted_packets == 0
    assert st.lost_packets == st.late_packets == 0 and st.decoded_packets == len(pk)
    assert dropped.corrupted == dropped.lost == 0


def _ouster_moved(tmp_path, k: int, by_frames: int):
    md = load_metadata(external(OUSTER + ".json"))
    src = external(OUSTER + ".pcap")
    pk = _packets(src, md.packet_size)[k]
    moved = np.frombuffer(pk.payload, np.uint8).copy()
    view = moved.view(md.profile.packet_dtype(md.pixels_per_column, md.columns_per_packet))
    view["columns"]["frame_id"] += np.uint16(by_frames % 65536)
    out = tmp_path / "moved.pcap"
    out.write_bytes(_with_payload(src.read_bytes(), pk.payload, moved.tobytes()))
    return md, src, out


@pytest.mark.parametrize("k", [0, 30, 63])
def test_an_ouster_packet_whose_frame_id_moved_50000_is_corrupted_not_a_loss(tmp_path, k):
    md, src, moved = _ouster_moved(tmp_path, k, 50_000)
    clean_frames, clean, _ = _open(src, metadata=md.path)
    frames, st, dropped = _open(moved, metadata=md.path)
    assert st.corrupted == 1 and dropped.corrupted == 1
    assert st.lost_packets <= clean.lost_packets + 1 and st.late == clean.late == 0
    assert frames == clean_frames
    # the live counter, with and without capture times
    pk = _packets(moved, md.packet_size)
    payload = np.frombuffer(b"".join(p.payload for p in pk), np.uint8).reshape(len(pk), -1)
    host = np.array([p.timestamp_ns for p in pk], np.int64)
    for with_host in (True, False):
        c = OusterCounter(md)
        for rows in np.array_split(np.arange(len(pk)), 3):
            c.update(payload[rows], host[rows] if with_host else None)
        assert c.count.corrupted == 1 and c.count.interruptions == 0
        assert c.count.lost <= 1


def test_the_loss_credit_never_grants_more_than_the_capture_time_holds():
    """Claims of 1000 lost packets at every other step of a 1 s stream of 1 ms packets: what is granted
    never exceeds the capture time (1000 periods) plus the capture-resolution allowance."""
    c = StreamContinuity(1e6)
    n = 1000
    host = 1_000_000_000 + np.arange(n, dtype=np.int64) * 1_000_000
    lost = np.where(np.arange(n) % 2 == 1, 1000, 0)
    granted = c.bound_lost(lost, np.diff(host, prepend=host[0]), np.arange(n) > 0, 1e6)
    assert granted.sum() <= n + CAPTURE_RESOLUTION_S * 1e3 + 1
    # packets 5 periods apart in capture time, with 4 missing between them: all 4 granted
    c = StreamContinuity(1e6)
    assert c.bound_lost(np.array([0, 4]), np.array([0, 5_000_000]), np.array([False, True]), 1e6).tolist() == [0, 4]


def _damaged(data: bytes, rng: np.random.Generator, start: int) -> bytes:
    """Random byte damage: a few bytes set to random values, a few bit flips, a few bytes swapped
    with a neighbour record's (anywhere after the file header, record headers included)."""
    b = bytearray(data)
    n = len(b)
    for at in rng.integers(start, n, int(rng.integers(1, 40))):
        b[at] = int(rng.integers(0, 256))
    for at in rng.integers(start, n, int(rng.integers(0, 20))):
        b[at] ^= 1 << int(rng.integers(0, 8))
    return bytes(b)


def _capacity(packets, period_ns) -> int:
    """The most packets the capture's time can hold: its capture-time span at the packet rate."""
    t = [p.timestamp_ns for p in packets]
    return int(np.rint((max(t) - min(t)) / period_ns + CAPTURE_RESOLUTION_S * 1e9 / period_ns)) + 1


@pytest.mark.parametrize("which", ["vlp16", "ouster"])
def test_damaged_copies_never_claim_more_losses_than_the_capture_holds(tmp_path, which):
    """100 randomly damaged copies of each reliability capture (seeded): every read either raises a
    LidarpktError or reports at most as many lost packets as the clean capture's time can hold, in
    the decoder and in the live counter."""
    if which == "vlp16":
        src, period, kw, size = external(VLP), VLP_PERIOD_NS, {}, 1206
        data = src.read_bytes()[: 24 + 500 * 1264]  # the first 500 records: the read stays fast
    else:
        md = load_metadata(external(OUSTER + ".json"))
        src, period, kw, size = external(OUSTER + ".pcap"), OUSTER_PERIOD_NS, {"metadata": md.path}, md.packet_size
        data = src.read_bytes()
    clean = tmp_path / "clean.pcap"
    clean.write_bytes(data)
    capacity = _capacity(_packets(clean, size), period)
    rng = np.random.default_rng(27)
    path = tmp_path / "damaged.pcap"
    worst = 0
    for _ in range(100):
        path.write_bytes(_damaged(data, rng, 24))
        try:
            _, _, dropped = _open(path, **kw)
        except LidarpktError:
            continue
        worst = max(worst, dropped.lost)
        assert dropped.lost <= capacity, (dropped, capacity)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pk = [p for p in PcapReader(path).packets() if len(p.payload) == size]
        if not pk:
            continue
        payload = np.frombuffer(b"".join(p.payload for p in pk), np.uint8).reshape(len(pk), size)
        host = np.array([p.timestamp_ns for p in pk], np.int64)
        c = VelodyneCounter() if which == "vlp16" else OusterCounter(md)
        try:
            c.update(payload, host)
        except LidarpktError:
            continue
        assert c.count.lost <= capacity, (c.count, capacity)
