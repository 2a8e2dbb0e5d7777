"""Decoding off the receive path (lidarpkt.pipeline.live: FrameTap, LiveDecoder; lidarpkt.view.tap), with real
threads: the caller never waits, what cannot be decoded or shown is dropped *and counted*, and the
frames that are decoded equal ``lidarpkt.open``'s whatever the batching."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import lidarpkt
from lidarpkt.pipeline.live import FrameTap, LiveDecoder
from lidarpkt.view.sources import play_capture
from lidarpkt.view.tap import FrameDropper
from lidarpkt.recorder.replay import read_capture
from lidarpkt.containers.udp import batch_from_packets
from test_view_capture import CANNED


def batches_of(path, size: int):
    packets = list(read_capture(str(path)))
    items = [(p.timestamp_ns, p.src, p.dst, p.payload) for p in packets]
    return [b for i in range(0, len(items), size) for b in batch_from_packets(items[i:i + size])]


def same_frames(got, want) -> None:
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert g.frame_id == w.frame_id and g.partial == w.partial and g.return_labels == w.return_labels
        np.testing.assert_array_equal(g.range_mm, w.range_mm)
        np.testing.assert_array_equal(g.reflectivity, w.reflectivity)
        np.testing.assert_array_equal(g.column_valid, w.column_valid)
        np.testing.assert_array_equal(g.xyz(), w.xyz())


@pytest.mark.parametrize("size", [1, 37, 4096])
@pytest.mark.parametrize("capture, metadata", [(CANNED / "vlp16-dual.pcap", None),
                                               (CANNED / "os1-64-dual.pcap", CANNED / "os1-64-dual.json")])
def test_live_decoder_equals_lidarpkt_open(capture, metadata, size):
    md = [lidarpkt.vendors.ouster.load_metadata(str(metadata))] if metadata else []
    decoder = LiveDecoder(md)
    got = [f for b in batches_of(capture, size) for f in decoder.push(b)] + decoder.finish()
    same_frames(got, list(lidarpkt.open(capture, metadata=str(metadata) if metadata else None)))
    assert decoder.unrouted_packets == 0  # every stream went to its sensor (IMU packets included)


def test_tap_never_blocks_and_counts_what_it_drops():
    batches = batches_of(CANNED / "vlp16-dual.pcap", 64)
    release = threading.Event()
    seen = []

    def slow(frame):
        release.wait(30)
        seen.append(frame)

    tap = FrameTap(LiveDecoder(), [slow], queue_bytes=4 * 64 * 1206)
    t = time.perf_counter()
    for b in batches:
        tap.offer([b])
    assert time.perf_counter() - t < 1.0  # the consumer is stuck; offering did not wait for it
    assert tap.dropped_packets > 0
    release.set()
    tap.close()
    decoded = sum(d.stats.packets for d in tap.decoder.decoders.values()) + tap.decoder.auxiliary_packets
    assert decoded > 0 and decoded + tap.dropped_packets == sum(len(b) for b in batches)  # each packet: one or other
    assert len(seen) == tap.frames


def test_dropper_drops_for_the_viewer_only_and_counts():
    frames = list(lidarpkt.open(CANNED / "vlp16-dual.pcap"))
    release, holding = threading.Event(), threading.Event()
    shown = []

    def slow_viewer(frame):
        holding.set()
        release.wait(30)
        shown.append(frame)

    drops = []
    dropper = FrameDropper(slow_viewer, depth=2, on_drop=drops.append)
    dropper(frames[0])
    assert holding.wait(10)  # the viewer is busy with the first frame
    t = time.perf_counter()
    for f in frames[1:]:
        dropper(f)
    assert time.perf_counter() - t < 0.5  # never waited for the viewer
    release.set()
    dropper.close()
    # one in the viewer's hands, two waiting, the rest dropped and counted
    assert len(shown) + dropper.dropped == len(frames) and dropper.dropped == len(frames) - 3
    assert drops == list(range(1, dropper.dropped + 1))
    assert [f.frame_id for f in shown] == [f.frame_id for f in frames[:3]]


def test_consumer_errors_are_kept_not_raised():
    batches = batches_of(CANNED / "vlp16-dual.pcap", 128)
    good = []

    def broken(frame):
        raise ValueError("viewer broke")

    tap = FrameTap(LiveDecoder(), [broken, good.append])
    tap.offer(batches)
    tap.close()
    assert len(good) == tap.frames == 7
    assert isinstance(tap.error, ValueError) and tap.consumer_errors == 7


def test_play_capture_paces_by_sensor_time_and_loops():
    frames = list(lidarpkt.open(CANNED / "vlp16-dual.pcap"))
    span_s = (frames[-1].timestamp_ns - frames[0].timestamp_ns) / 1e9
    t = time.perf_counter()
    got = list(play_capture(CANNED / "vlp16-dual.pcap", rate=4.0))
    took = time.perf_counter() - t
    assert [f.frame_id for f in got] == [f.frame_id for f in frames]
    assert took >= span_s / 4 * 0.95
    stop = threading.Event()
    looped = []
    for f in play_capture(CANNED / "vlp16-dual.pcap", rate=50.0, loop=True, stop=stop):
        looped.append(f)
        if len(looped) == 2 * len(frames) + 1:
            stop.set()
    assert [f.frame_id for f in looped[:2 * len(frames)]] == [f.frame_id for f in frames] * 2


@pytest.mark.filterwarnings("ignore::lidarpkt.errors.DroppedPacketsWarning")  # the file's summary of the same counts
def test_live_and_files_share_one_driver_sensor_limit_and_unrouted_streams_included(tmp_path):
    """The same capture pushed live and read as a file goes through one driver (lidarpkt.pipeline.reader.Driver):
    with two sensors and max_sensors=1, both warn once that the second is not decoded and count its packets,
    and a stream of no sensor, as unrouted, in the same streams."""
    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.errors import SkippedPacketWarning
    from lidarpkt.writers.pcap import write_pcap

    packets = list(read_capture(str(CANNED / "vlp16-dual.pcap")))
    other = Endpoint("192.168.1.202", 2368)
    mixed = [p for q in packets for p in (q, Packet(q.timestamp_ns + 1, other, q.dst, q.payload))]
    mixed.append(Packet(packets[-1].timestamp_ns + 5, other, Endpoint("10.0.0.9", 9999), b"junk" * 9))
    write_pcap(tmp_path / "two.pcap", mixed)
    with pytest.warns(SkippedPacketWarning, match="more than 1 sensors"):
        reader = lidarpkt.open(tmp_path / "two.pcap", max_sensors=1)
        want = list(reader)
    decoder = LiveDecoder(max_sensors=1)
    items = [(p.timestamp_ns, p.src, p.dst, p.payload) for p in read_capture(str(tmp_path / "two.pcap"))]
    with pytest.warns(SkippedPacketWarning, match="more than 1 sensors"):
        got = [f for b in batch_from_packets(items) for f in decoder.push(b)] + decoder.finish()
    same_frames(got, want)
    assert len(decoder.decoders) == len(reader.decoders) == 1
    assert decoder.unrouted_packets == reader.stats.unrouted_packets == len(packets) + 1
    assert set(decoder.stats.unrouted_streams) == set(reader.stats.unrouted_streams)
