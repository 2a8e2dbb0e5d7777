"""Back to pcap (``lidarpkt export --format pcap``): the raw packets of a bag, an MCAP or a pcapng
written as a pcap whose UDP payloads are the packets inside, in capture order, with their capture
times; read back by readers nobody here wrote (ouster-sdk's libtins reader, velodyne_decoder,
ouster-sdk's frame source)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from conftest import external
from lidarpkt.cli import main
from lidarpkt.errors import UnsupportedContainerError
from lidarpkt.core.packet import Endpoint, Packet, PacketBatch
from lidarpkt.vendors.registry import open_packets
from lidarpkt.writers.pcap import PcapBatchWriter, write_pcap
from reference_tools import ouster_sdk_pcap_packets

NEBULA_VLP16 = "nebula/vlp16/1673400471837873222"
OS0 = "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap"
OS0_JSON = "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"
OSF = "ouster-sdk/osf_fw_3.2_10scans.osf"


def _packets_inside(path) -> list[Packet]:
    return list(open_packets(path).packets())


def _export(tmp_path, src, *extra) -> "Path":  # noqa: F821 - pathlib's, returned
    out = tmp_path / "out"
    assert main(["export", str(src), "-o", str(out), "--format", "pcap", "--workers", "1", "-q", *extra]) == 0
    (pcap,) = out.glob("*.pcap")
    return pcap


def _assert_same_packets(pcap, inside: list[Packet], *, ports: dict[int, int] | None = None) -> None:
    """ouster-sdk's reader (libtins, reassembling IPv4 fragments) sees exactly ``inside``: payloads in
    order, capture times to its precision (whole microseconds, as a float of seconds), and (a bag's)
    the expected port per payload size."""
    theirs = ouster_sdk_pcap_packets(pcap)
    assert len(theirs) == len(inside) > 0
    assert [p for *_, p in theirs] == [p.payload for p in inside]
    times = np.array([t for _, _, t, _ in theirs])
    assert np.abs(times - np.array([p.timestamp_ns for p in inside]) / 1e9).max() < 1.5e-6
    # and exactly in nanoseconds, read back by lidarpkt's own reader
    assert [p.timestamp_ns for p in _packets_inside(pcap)] == [p.timestamp_ns for p in inside]
    for src, dst, _, payload in theirs:
        if ports is not None:
            assert dst.port == src.port == ports[len(payload)]


def test_batches_of_interleaved_streams_come_out_in_capture_order_as_write_pcap_frames_them(tmp_path):
    """Batches interleave (one chunk's batches of three streams), datagrams are fragmented, one payload
    size is odd, one stream is IPv6: the batch writer's file is byte for byte write_pcap's file of the
    same packets in capture order, and ouster-sdk's reader gets the payloads back."""
    rng = np.random.default_rng(7)
    streams = [(Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368), 1206),
               (Endpoint("192.168.1.201", 8308), Endpoint("255.255.255.255", 8308), 511),
               (Endpoint("10.0.0.2", 7502), Endpoint("10.0.0.1", 7502), 3329),
               (Endpoint("fe80::2", 7503), Endpoint("fe80::1", 7503), 48)]
    which = rng.integers(0, len(streams), 300)
    packets = [Packet(1_600_000_000_123_456_789 + 997 * i, streams[k][0], streams[k][1],
                      rng.integers(0, 256, streams[k][2], dtype=np.uint8).tobytes()) for i, k in enumerate(which)]
    write_pcap(tmp_path / "ref.pcap", packets, nanosecond=True)
    with PcapBatchWriter(tmp_path / "batches.pcap") as writer:
        for chunk in range(0, len(packets), 64):  # a reader's batches: per chunk, by first packet
            rows = range(chunk, min(chunk + 64, len(packets)))
            groups = {}
            for i in rows:
                groups.setdefault(int(which[i]), []).append(i)
            for k, idx in sorted(groups.items(), key=lambda kv: kv[1][0]):
                writer.write(PacketBatch(streams[k][0], streams[k][1],
                                         np.array([packets[i].timestamp_ns for i in idx], np.int64),
                                         np.stack([np.frombuffer(packets[i].payload, np.uint8) for i in idx]),
                                         np.array(idx, np.int64)))
    assert writer.packets_written == len(packets)
    assert (tmp_path / "batches.pcap").read_bytes() == (tmp_path / "ref.pcap").read_bytes()
    _assert_same_packets(tmp_path / "batches.pcap", packets)


def test_nebula_vlp16_bag_to_pcap_is_read_by_velodyne_decoder(tmp_path):
    """A rosbag2 of VelodyneScan messages: its 603 packets, in order, on the VLP-16's factory ports;
    velodyne_decoder reads the pcap into the same points as the bag's packets fed to it directly."""
    vd = pytest.importorskip("velodyne_decoder")
    bag = external(NEBULA_VLP16)
    inside = _packets_inside(bag)
    pcap = _export(tmp_path, bag)
    _assert_same_packets(pcap, inside, ports={1206: 2368})
    assert len(inside) == 603
    cfg = vd.Config(model=vd.Model.VLP16)
    scans = [points for _, points in vd.read_pcap(str(pcap), cfg)]
    direct = vd.PacketVector()
    for p in inside:
        direct.append(vd.VelodynePacket(p.timestamp_ns / 1e9, p.payload))
    _, points = vd.ScanDecoder(cfg).decode(direct, True)
    assert len(scans) == 4 and sum(len(s) for s in scans) == len(points) > 50_000
    xyzi = np.column_stack([points[name] for name in ("x", "y", "z", "intensity")])  # times are per scan
    assert np.array_equal(np.concatenate(scans)[:, :4], xyzi)


def test_ouster_mcap_written_by_decode_to_pcap_is_read_by_ouster_sdk(tmp_path):
    """`decode --topics packets` keeps an Ouster capture's lidar and IMU packets in an MCAP (addresses
    gone); export --format pcap puts them back on the metadata's ports, and ouster-sdk makes the same
    frame from it as from the original capture, field for field."""
    sdk_pcap = pytest.importorskip("ouster.sdk.pcap")
    mcap = tmp_path / "os0.mcap"
    assert main(["decode", str(external(OS0)), "--metadata", str(external(OS0_JSON)), "-o", str(mcap),
                 "--topics", "packets", "-q"]) == 0
    # the MCAP keeps each chunk's IMU packets after its lidar packets: capture order is the times' order
    inside = sorted(_packets_inside(mcap), key=lambda p: p.timestamp_ns)
    assert [p.payload for p in inside] == [p.payload for p in _packets_inside(external(OS0))]
    pcap = _export(tmp_path, mcap)
    _assert_same_packets(pcap, inside, ports={8448: 7502, 48: 7503})

    def frames(path):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return [fs[0] for fs in sdk_pcap.PcapFrameSetSource(str(path), meta=[str(external(OS0_JSON))])
                    if fs[0] is not None]

    theirs, original = frames(pcap), frames(external(OS0))
    assert len(theirs) == len(original) == 1
    for name in original[0].fields:
        assert np.array_equal(theirs[0].field(name), original[0].field(name)), name
    assert np.array_equal(theirs[0].timestamp, original[0].timestamp)


@pytest.mark.parametrize("container", ["pcap", "pcapng"])
def test_a_pcap_or_pcapng_keeps_its_addresses(tmp_path, container):
    """A pcap/pcapng input keeps each packet's own endpoints (Ouster's loopback capture; as pcapng,
    microsecond and nanosecond interfaces alike, and IPv6)."""
    from lidarpkt.writers.pcap import Interface, write_pcapng

    src = external(OS0)
    if container == "pcapng":
        packets = [Packet(p.timestamp_ns, Endpoint("fd00::2", p.src.port), Endpoint("fd00::1", p.dst.port), p.payload)
                   if p.dst.port == 7503 else p for p in _packets_inside(src)]
        src = tmp_path / "os0.pcapng"
        write_pcapng(src, packets, interfaces=[Interface("ethernet", tsresol=9), Interface("linux_sll")],
                     interface_of=lambda p: p.dst.port == 7503)
    inside = _packets_inside(src)
    pcap = _export(tmp_path, src)
    _assert_same_packets(pcap, inside)
    assert [(str(s), str(d)) for s, d, _, _ in ouster_sdk_pcap_packets(pcap)] == \
        [(str(p.src), str(p.dst)) for p in inside]


def test_time_order_holds_a_bounded_window():
    """Batches of two streams whose file order is not their time order come out by time, re-indexed;
    with a window shorter than the disorder the late packets keep their file place (bounded memory)."""
    from lidarpkt.archive.packets import time_ordered

    a, b = (Endpoint("1.0.0.1", 1), Endpoint("1.0.0.2", 1)), (Endpoint("1.0.0.1", 2), Endpoint("1.0.0.2", 2))

    def batch(ends, times, first):
        t = np.asarray(times, np.int64)
        return PacketBatch(*ends, t, (t % 251).astype(np.uint8).reshape(-1, 1), np.arange(first, first + t.size))

    file_order = [batch(a, range(0, 100, 10), 0), batch(a, range(100, 200, 10), 10),
                  batch(b, range(5, 200, 10), 20), batch(a, range(200, 300, 10), 40)]  # b's stored late
    out = list(time_ordered(file_order, window_ns=1000))
    times = np.concatenate([x.timestamp_ns for x in out])[np.argsort(np.concatenate([x.index for x in out]))]
    assert times.tolist() == sorted(times.tolist()) and times.size == 50
    assert sorted(np.concatenate([x.index for x in out]).tolist()) == list(range(50))
    narrow = list(time_ordered(file_order, window_ns=40))  # released before b arrives: b stays late
    order = np.argsort(np.concatenate([x.index for x in narrow]))
    late = np.concatenate([x.timestamp_ns for x in narrow])[order]
    assert late.size == 50 and late.tolist() != sorted(late.tolist())
    assert [int(x.index[0]) for x in narrow] == sorted(int(x.index[0]) for x in narrow)


def test_an_osf_file_gets_one_clear_error(tmp_path, capsys):
    from lidarpkt.archive.packets import write_packets_pcap

    osf = external(OSF)
    with pytest.raises(UnsupportedContainerError, match="OSF file: it holds decoded frames, not the sensor's UDP"):
        write_packets_pcap(osf, tmp_path / "x.pcap")
    assert not (tmp_path / "x.pcap").exists()
    assert main(["export", str(osf), "-o", str(tmp_path / "out"), "--format", "pcap", "--workers", "1"]) == 1
    err = capsys.readouterr().err
    assert "OSF file" in err and "Traceback" not in err
    assert not list((tmp_path / "out").glob("*.pcap"))


def test_write_pcap_frames_interleaved_streams_together_as_the_one_packet_builder_does(tmp_path):
    """write_pcap frames the packets of each stream of a window together (the NumPy builder on many rows):
    its records are those of frames_for (the same builder on one row) packet by packet, the IP identification
    counting packets from 1 in capture order, across windows; read back, every payload is in its place."""
    from lidarpkt.containers.pcap_reader import read_packets
    from lidarpkt.writers import framing
    from lidarpkt.writers.pcap import pcap_bytes

    rng = np.random.default_rng(7)
    ends = [(Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368), 1206),
            (Endpoint("192.168.1.201", 8308), Endpoint("255.255.255.255", 8308), 512),
            (Endpoint("10.0.0.2", 7502), Endpoint("10.0.0.1", 7502), 3300),  # fragmented
            (Endpoint("fe80::2", 7503), Endpoint("fe80::1", 7503), 2000)]  # IPv6, fragmented
    kinds = rng.integers(0, len(ends), framing.WINDOW_PACKETS + 500)
    packets = [Packet(1_700_000_000_000_000_000 + i * 50_000, ends[k][0], ends[k][1],
                      rng.integers(0, 256, ends[k][2], dtype=np.uint8).tobytes()) for i, k in enumerate(kinds)]
    write_pcap(tmp_path / "x.pcap", packets)
    one_by_one = [(p.timestamp_ns, f) for i, p in enumerate(packets)
                  for f in framing.frames_for(p, ident=(i + 1) & 0xFFFF)]
    assert (tmp_path / "x.pcap").read_bytes() == pcap_bytes(one_by_one)
    back = list(read_packets(tmp_path / "x.pcap"))
    assert [(p.timestamp_ns, p.payload) for p in back] == [(p.timestamp_ns, p.payload) for p in packets]
