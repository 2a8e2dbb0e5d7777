"""Live UDP reception as a packet source (``lidarpkt.containers.udp``): opened like a capture file
(``open_packet_source("udp://...")``), its batches decoded by the same router as ``lidarpkt.open``'s."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import UsageError
from lidarpkt.containers import open_packet_source
from lidarpkt.containers.pcap_reader import read_packets
from lidarpkt.containers.udp import UdpSource, parse_udp_url
from lidarpkt.pipeline.live import LiveDecoder
from conftest import REPO_ROOT

CAPTURE = REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "vlp16-strongest.pcap"


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_udp_url_opens_a_source_whose_batches_decode_like_the_capture():
    packets = list(read_packets(CAPTURE))
    data = [p for p in packets if len(p.payload) == 1206]
    port = _free_port()
    source = open_packet_source(f"udp://127.0.0.1:{port}")
    assert isinstance(source, UdpSource) and source.recorded_sensor_file() is None
    got = []
    decoder = LiveDecoder()
    frames = []

    def consume():
        for batch in source.batches():  # starts the receive thread; ends after stop() and the last batch
            got.append(batch)
            frames.extend(decoder.push(batch))

    reader = threading.Thread(target=consume)
    try:
        reader.start()
        time.sleep(0.2)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for p in data:
                tx.sendto(p.payload, ("127.0.0.1", port))
                if len(data) > 200:
                    time.sleep(0)  # let the receive thread keep up on a loaded machine
        deadline = time.monotonic() + 10
        while sum(len(b) for b in got) < len(data) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        source.stop()
        reader.join(timeout=10)
        source.close()
    assert not reader.is_alive()
    payloads = np.concatenate([b.payload for b in got])
    assert [bytes(r) for r in payloads] == [p.payload for p in data]
    assert all(b.dst.port == port for b in got)
    frames += decoder.finish()
    # the live router's frames are the capture's (same packets, same decoder); frame times take the hour
    # from the host clock live, so compare the images
    want = list(lidarpkt.open(CAPTURE))
    assert len(frames) == len(want)
    for a, b in zip(frames, want):
        assert np.array_equal(a.range_mm, b.range_mm) and np.array_equal(a.reflectivity, b.reflectivity)


@pytest.mark.parametrize("url, bind, ports", [("udp://:2368,8308", None, [2368, 8308]),
                                              ("udp://10.5.6.1:7502", "10.5.6.1", [7502])])
def test_udp_url(url, bind, ports):
    assert parse_udp_url(url) == (bind, ports)


@pytest.mark.parametrize("url", ["udp://host", "udp://:0", "udp://:x", "udp://:70000"])
def test_udp_url_rejects(url):
    with pytest.raises(UsageError, match="udp://"):
        parse_udp_url(url)
