"""The packet-source layer's contract: one opener for every container, the PacketSource protocol, filters
that raise where they cannot apply, file magic in one place, and the fast-path counter of ReadStats."""

from __future__ import annotations

import struct

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import LidarpktError, UnsupportedContainerError, UnsupportedFilterError
from lidarpkt.core.packet import Packet
from lidarpkt.containers.pcap_reader import PcapReader, read_packets
from lidarpkt.writers.framing import frames_for
from lidarpkt.writers.pcap import write_pcap, write_pcap_records, write_pcapng
from lidarpkt.containers import PacketSource, container_kind, open_packet_source
from lidarpkt.containers.bags import BagReader
from lidarpkt.vendors.registry import bag_messages
from lidarpkt.containers.magic import PCAP_MAGIC_BYTES, format_from_magic

from conftest import REPO_ROOT, external
from reference_tools import velodyne_scan_mcap

CANNED = REPO_ROOT / "lidarpkt" / "fixtures" / "canned"
NEBULA = "nebula/vlp16/1673400471837873222"


def _vlp_mcap(tmp_path):
    packets = [p for p in read_packets(CANNED / "vlp16-strongest.pcap") if len(p.payload) == 1206][:60]
    payload = np.stack([np.frombuffer(p.payload, np.uint8) for p in packets])
    host = np.array([p.timestamp_ns for p in packets], np.int64)
    path = tmp_path / "scan.mcap"
    path.write_bytes(velodyne_scan_mcap(payload, host, packets_per_message=20))
    return path, payload


def test_one_opener_for_every_container(tmp_path):
    pcap = CANNED / "vlp16-strongest.pcap"
    ng = tmp_path / "v.pcapng"
    write_pcapng(ng, read_packets(pcap))
    mcap, _ = _vlp_mcap(tmp_path)
    bag = external(NEBULA)
    for path, reader_type, kind in ((pcap, PcapReader, "pcap"), (ng, PcapReader, "pcap"), (mcap, BagReader, "mcap"),
                                    (bag, BagReader, "rosbag2"), (bag / "1673400471837873222_0.db3", BagReader, "rosbag2")):
        src = open_packet_source(path, messages=bag_messages())
        assert isinstance(src, reader_type) and isinstance(src, PacketSource), path
        assert container_kind(path) == kind
        batches = list(src.batches())
        packets = list(src.packets())
        assert sum(len(b) for b in batches) == len(packets) > 0
        # packets() is batches() one by one, in ordinal order
        order = np.argsort(np.concatenate([b.index for b in batches]), kind="stable")
        flat = [p for b in batches for p in b.packets()]
        assert [flat[i].payload for i in order] == [p.payload for p in packets]
        assert src.recorded_sensor_file() is None


def test_magic_is_known_once():
    # every pcap/pcapng magic lidarpkt.open accepts is one the pcap reader recognises, in both byte orders
    assert {format_from_magic(m) for m in PCAP_MAGIC_BYTES} == {"pcap", "pcapng"}
    for magic in (0xA1B2C3D4, 0xA1B23C4D, 0xA1B2CD34):
        for order in "<>":
            assert format_from_magic(struct.pack(order + "I", magic)) == "pcap"
    assert format_from_magic(b"\x89MCA") is None


def test_unsupported_container_names_the_file(tmp_path):
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"GIF89a and more")
    with pytest.raises(UnsupportedContainerError, match="junk.bin.*47 49 46"):
        open_packet_source(junk)


@pytest.mark.parametrize("options", [{"port": [2368]}, {"topic": "/x"}, {"ports": [2368], "bogus": 1}])
def test_unknown_filter_raises_a_lidarpkt_error_for_pcap(options):
    with pytest.raises(UnsupportedFilterError, match="unknown packet filter") as info:
        open_packet_source(CANNED / "vlp16-strongest.pcap", **options)
    assert isinstance(info.value, LidarpktError) and isinstance(info.value, TypeError)


@pytest.mark.parametrize("name", ["ports", "src_addresses"])
def test_address_filters_raise_for_bags_instead_of_being_ignored(tmp_path, name):
    mcap, _ = _vlp_mcap(tmp_path)
    value = [2368] if name == "ports" else ["192.168.1.201"]
    for path in (mcap, external(NEBULA)):
        with pytest.raises(UnsupportedFilterError, match=f"{name}=.*records no UDP ports or addresses.*topics="):
            open_packet_source(path, **{name: value})
        with pytest.raises(UnsupportedFilterError):
            BagReader(path, **{name: value}, messages=bag_messages())
        with pytest.raises(UnsupportedFilterError):
            lidarpkt.open(path, **{name: value})
    with pytest.raises(UnsupportedFilterError, match="unknown packet filter"):
        BagReader(mcap, batch_packets=10, messages=bag_messages())
    # None means "no filter" everywhere, and the filters bags do have still work
    assert len(list(open_packet_source(mcap, messages=bag_messages(), ports=None, src_addresses=None).batches())) == 3
    assert list(open_packet_source(mcap, messages=bag_messages(), payload_sizes=[512]).batches()) == []


def test_pcap_filters_still_filter():
    pcap = CANNED / "vlp16-strongest.pcap"
    data = list(open_packet_source(pcap, ports=[2368]).packets())
    position = list(open_packet_source(pcap, ports=[8308]).packets())
    everything = list(open_packet_source(pcap).packets())
    assert data and position and len(data) + len(position) == len(everything)
    assert {len(p.payload) for p in data} == {1206} and {len(p.payload) for p in position} == {512}


def _ouster_packets(n: int = 40) -> list[Packet]:
    path = external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap")  # recorded on loopback: unfragmented
    return [p for p in read_packets(path) if len(p.payload) > 20_000][:n]


@pytest.mark.parametrize("name, datagrams", [("ouster-sdk/same_ports_legacy.pcap", 2),
                                             ("ouster-sdk/same_ports_nonlegacy.pcap", 2), ("canned", 128)])
def test_real_and_canned_fragment_trains_take_the_fast_path(name, datagrams, monkeypatch):
    from lidarpkt.containers import pcap_walk

    # each file in one read block: a train cut by a block's end is put together by the per-record path
    monkeypatch.setattr(pcap_walk, "FIRST_BLOCK_BYTES", 8 << 20)
    path = CANNED / "os1-64-dual.pcap" if name == "canned" else external(name)
    reader = PcapReader(path)
    list(reader.batches())
    assert reader.stats.reassembled == datagrams and reader.stats.reassembled_vectorised == datagrams
    # duplicate_id.pcap reuses an IP ID with a stale fragment pending: the general path decides
    reader = PcapReader(external("ouster-sdk/duplicate_id.pcap"))
    list(reader.batches())
    assert reader.stats.reassembled == 1 and reader.stats.reassembled_vectorised == 0


def test_stats_count_the_vectorised_fragment_fast_path(tmp_path):
    # OS-2-128 lidar datagrams (24,832 B) as 17 in-order IPv4 fragments each: every train takes the fast path
    packets = _ouster_packets()
    ordered = tmp_path / "ordered.pcap"
    write_pcap(ordered, packets, mtu=1500)
    reader = PcapReader(ordered)
    got = list(reader.packets())
    assert [p.payload for p in got] == [p.payload for p in packets]
    st = reader.stats
    assert st.reassembled == len(packets) and st.reassembled_vectorised == len(packets)
    assert st.fragments == 17 * len(packets)
    assert st.as_dict()["reassembled_vectorised"] == len(packets)
    # the same fragments, each train's last two swapped: only the per-record reassembler can take them
    records = []
    for k, p in enumerate(packets):
        frames = frames_for(p, ident=k + 1, mtu=1500)
        frames[-2], frames[-1] = frames[-1], frames[-2]
        records += [(p.timestamp_ns, f) for f in frames]
    swapped = tmp_path / "swapped.pcap"
    write_pcap_records(swapped, records)
    reader = PcapReader(swapped)
    assert [p.payload for p in reader.packets()] == [p.payload for p in packets]
    assert reader.stats.reassembled == len(packets) and reader.stats.reassembled_vectorised == 0


def test_open_packet_source_passes_reader_options():
    src = open_packet_source(CANNED / "os1-64-dual.pcap", batch_packets=50, payload_sizes=[48])
    batches = list(src.batches())
    assert batches and all(len(b) <= 50 and b.payload_size == 48 for b in batches)
    assert src.stats.filtered == 128 and src.stats.yielded == 20


def test_open_takes_typed_keyword_options_with_the_readers_defaults():
    import dataclasses
    import inspect
    import pydoc

    from lidarpkt.pipeline.options import OpenOptions
    from lidarpkt.pipeline.reader import FrameReader, open_frames

    assert lidarpkt.open is open_frames
    sig = inspect.signature(lidarpkt.open)
    params = list(sig.parameters.values())[1:]
    assert params and all(p.kind is p.KEYWORD_ONLY and p.annotation is not p.empty for p in params)
    assert not any(p.kind is p.VAR_KEYWORD for p in sig.parameters.values())
    # one declaration of the options (OpenOptions): lidarpkt.open and FrameReader show exactly its fields
    declared = [(f.name, f.default, f.type) for f in dataclasses.fields(OpenOptions)]
    assert [(p.name, p.default, p.annotation) for p in params] == declared
    reader_params = list(inspect.signature(FrameReader).parameters.values())[1:]
    assert [(p.name, p.default, p.annotation) for p in reader_params] == declared
    for shown in (pydoc.render_doc(lidarpkt.open), pydoc.render_doc(FrameReader)):
        assert all(f"{p.name}: " in shown for p in params)  # every option listed in help(), with its text
        assert "{options}" not in shown and OpenOptions.__dataclass_fields__["cut_on_block"].metadata["doc"][:40] in \
            " ".join(shown.split())
    for make in (lidarpkt.open, FrameReader):
        with pytest.raises(TypeError, match="unexpected keyword argument 'cut_angle'"):
            make(CANNED / "vlp16-strongest.pcap", cut_angle=90)  # a misspelt option is refused at once
    frames = list(lidarpkt.open(CANNED / "vlp16-strongest.pcap", ports=[2368], batch_packets=64, read_ahead=False))
    assert frames and sum(f.counters.lost_packets for f in frames) == 0
