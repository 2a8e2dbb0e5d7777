"""The receive thread over real loopback sockets, and loss accounting on real captures."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from lidarpkt.errors import PortInUseError
from lidarpkt.vendors.ouster.metadata_json import load_metadata
from lidarpkt.containers.pcap_reader import read_batches, read_packets
from lidarpkt.vendors import registry
from lidarpkt.vendors.ouster.stream import PacketCounter as OusterCounter
from lidarpkt.vendors.velodyne.stream import PacketCounter as VelodyneCounter
from lidarpkt.containers.udp import UdpSource
from conftest import external


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _drain_until(cap: UdpSource, n: int, timeout_s: float = 60.0) -> list:
    """What the capture queued, until ``n`` items or ``timeout_s`` (a generous bound: the loop ends on the count)."""
    got: list = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        got += cap.drain(timeout=0.05)
    return got


def test_capture_receives_real_payloads_in_order_with_kernel_times_and_destination():
    packets = list(read_packets(external("rust-lidar-utils/velodyne_vlp16.pcap")))
    port = _free_port()
    with UdpSource([port], bind="127.0.0.1") as cap:
        cap.start()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            before = time.time_ns()
            for p in packets:
                tx.sendto(p.payload, ("127.0.0.1", port))
            src_port = tx.getsockname()[1]
            got = _drain_until(cap, len(packets))
            after = time.time_ns()
    assert [g[3] for g in got] == [p.payload for p in packets]
    times = [g[0] for g in got]
    assert times == sorted(times) and before <= times[0] and times[-1] <= after
    assert {g[1] for g in got} == {("127.0.0.1", src_port)}
    assert {g[2] for g in got} == {("127.0.0.1", port)}
    assert cap.stats.received == len(packets) and cap.stats.queue_overflow == 0


def test_capture_reports_the_buffer_the_kernel_granted():
    port = _free_port()
    with UdpSource([port], bind="127.0.0.1", rcvbuf_bytes=1 << 20) as cap:
        granted = cap.stats.rcvbuf_granted[port]
        raw = cap._sockets[0][0].getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    assert granted == raw // 2 and granted > 0


def test_port_in_use_is_a_clear_error():
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    port = holder.getsockname()[1]
    try:
        with pytest.raises(PortInUseError, match=f"port {port}.*already in use"):
            UdpSource([port], bind="127.0.0.1")
    finally:
        holder.close()


def test_queue_overflow_is_counted_not_blocking():
    port = _free_port()
    payload = bytes(1206)
    with UdpSource([port], bind="127.0.0.1", queue_bytes=10 * 1206) as cap:
        cap.start()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for _ in range(50):
                tx.sendto(payload, ("127.0.0.1", port))
        deadline = time.monotonic() + 60
        while cap.stats.received < 50 and time.monotonic() < deadline:
            time.sleep(0.01)
        got = _drain_until(cap, 10)
    assert cap.stats.received == 50
    assert len(got) == 10 and cap.stats.queue_overflow == 40


def test_a_signal_handler_outliving_the_wait_does_not_make_drain_wait_for_the_next_datagram():
    """CPython's SimpleQueue.get(timeout) waits for the next put when a signal handler runs past its
    deadline: `lidarpkt record`, told to stop by SIGTERM just as the packets stopped, never returned
    (seen twice in CI, its stack in drain). A handler that outlives drain's timeout must give an
    empty drain, not the datagram sent seconds later."""
    import signal
    import threading

    port = _free_port()

    def slow_handler(_signum, _frame) -> None:
        time.sleep(0.2)  # as a process descheduled on a loaded machine while handling SIGTERM

    previous = signal.signal(signal.SIGUSR1, slow_handler)
    main = threading.main_thread().ident
    with UdpSource([port], bind="127.0.0.1") as cap, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        cap.start()
        # far later than any descheduling of this process on a loaded machine (cancelled when done)
        late = threading.Timer(30.0, lambda: tx.sendto(b"late", ("127.0.0.1", port)))
        try:
            threading.Timer(0.01, lambda: signal.pthread_kill(main, signal.SIGUSR1)).start()
            late.start()
            got = cap.drain(timeout=0.05)
        finally:
            late.cancel()
            signal.signal(signal.SIGUSR1, previous)
        assert got == []


def test_one_read_is_bounded_so_a_flood_cannot_keep_the_thread_from_stopping():
    """A sender that never pauses (another program, a replay at --max) kept the receive thread in
    its read loop, deaf to stop(): one read takes at most READ_BATCH datagrams, then the thread
    looks at the stop flag again; the backlog is still all read, in order."""
    from lidarpkt.containers.udp import READ_BATCH

    port = _free_port()
    n = READ_BATCH + 10
    with UdpSource([port], bind="127.0.0.1") as cap:  # not started: the reads are driven here
        (sock, _), = cap._sockets
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for i in range(n):
                tx.sendto(i.to_bytes(4, "little"), ("127.0.0.1", port))
        time.sleep(0.2)
        assert cap._read_all(sock, port) is True  # more may be waiting
        assert len(cap.drain(timeout=0.0, max_items=n)) == READ_BATCH
        assert cap._read_all(sock, port) is False  # the rest, then the socket is empty
        rest = cap.drain(timeout=0.0, max_items=n)
        assert [int.from_bytes(it[3], "little") for it in rest] == list(range(READ_BATCH, n))


def test_kernel_drops_are_reported_through_so_rxq_ovfl():
    port = _free_port()
    payload = bytes(1206)
    # a tiny kernel buffer and nobody reading: the kernel must drop, and say how many
    with UdpSource([port], bind="127.0.0.1", rcvbuf_bytes=4096) as cap:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for _ in range(200):
                tx.sendto(payload, ("127.0.0.1", port))
            cap.start()
            got = _drain_until(cap, 1, 2.0)
            tx.sendto(payload, ("127.0.0.1", port))  # the drop count rides on the next datagram read
            got += _drain_until(cap, 1, 2.0)
    assert len(got) >= 2
    assert cap.stats.kernel_dropped > 0
    assert cap.stats.kernel_dropped + cap.stats.received == 201


# ------------------------------------------------------------------ loss from the packets themselves
def _velodyne_payloads(rel: str) -> np.ndarray:
    return np.concatenate([b.payload for b in read_batches(external(rel)) if b.payload_size == 1206])


@pytest.mark.parametrize("rel, rotations", [
    # 20 Hz; SOURCES.md's "50 wraps" counts packets whose first block wrapped, but the last packet wraps
    # inside too: 51 rotations completed, as the decoder (52 frames, VeloView's count) completes them
    ("veloview/vlp-16-test-90deg-1-50-frames.pcap", 51),
    ("rust-lidar-utils/velodyne_vlp16.pcap", 1),
    ("rust-lidar-utils/velodyne_example.pcap", 1),
])
def test_velodyne_real_captures_show_no_loss_and_their_known_wraps(rel, rotations):
    t = VelodyneCounter()
    payload = _velodyne_payloads(rel)
    for part in np.array_split(payload, 7):  # batch boundaries must not matter
        t.update(part)
    assert (t.count.packets, t.count.lost, t.count.out_of_order, t.count.frames) == (len(payload), 0, 0, rotations)


def test_velodyne_dropped_and_repeated_packets_are_counted_exactly():
    payload = _velodyne_payloads("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    drop = [10, 11, 12, 500, 1500]
    kept = np.delete(payload, drop, axis=0)
    kept = np.insert(kept, 700, kept[699], axis=0)  # a duplicate
    t = VelodyneCounter()
    t.update(kept)
    assert t.count.lost == len(drop) and t.count.out_of_order == 1


def test_velodyne_dual_mode_period_from_the_real_dual_bag():
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages

    batches = list(BagReader(external("nebula/vlp16/1673400471837873222"), messages=bag_messages()).batches())
    payload = np.concatenate([b.payload for b in batches])
    assert set(payload[:, 1204].tolist()) == {0x39}
    t = VelodyneCounter()
    t.update(payload)
    assert (t.count.lost, t.count.out_of_order) == (0, 0)  # packets every 663.552 µs, as the manual says
    t2 = VelodyneCounter()
    t2.update(np.delete(payload, [5, 300], axis=0))
    assert t2.count.lost == 2


@pytest.mark.parametrize("pcap, meta, changes", [
    ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", "ouster-sdk/OS-1-64_sensor_config_reduced.json", 0),
    ("rust-lidar-utils/ouster_example.pcap", "rust-lidar-utils/ouster_example.json", None),
    ("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json", 0),
])
def test_ouster_real_captures_loss_counting(pcap, meta, changes):
    md = load_metadata(external(meta))
    setup = registry.setup(registry.load_sensor_files([md]))
    lidar = np.concatenate([b.payload for b in read_batches(external(pcap))
                            if (m := registry.classify(b, setup)) is not None and m.lidar])
    t = OusterCounter(md)
    t.update(lidar)
    assert (t.count.lost, t.count.out_of_order) == (0, 0)
    if changes is not None:
        assert t.count.frames == changes
    t2 = OusterCounter(md)
    for part in np.array_split(np.delete(lidar, [3, 4, 40], axis=0), 3):
        t2.update(part)
    assert t2.count.lost == 3 and t2.count.out_of_order == 0


def _kinds(pcap, *files):
    """(payload size, stream kind text, decodable) of the first batch of each stream of a capture."""
    setup = registry.setup(registry.load_sensor_files(list(files)))
    seen = {}
    for b in read_batches(external(pcap)):
        if b.payload_size not in seen:
            m = registry.classify(b, setup)
            seen[b.payload_size] = (str(m.stream), m.decodable) if m is not None else ("other", False)
    return seen


def test_stream_kinds_from_the_packets_and_the_sensor_files():
    assert _kinds("veloview/vlp-16-test-90deg-1-50-frames.pcap") == {
        1206: ("velodyne_data", True), 512: ("velodyne_position", True)}
    # a legacy OS1-64 without its metadata: recognised by its size and headers, not decodable
    assert _kinds("ouster-sdk/OS-1-64_1024x10_fw20.pcap")[12608] == ("ouster_lidar", False)
    md = load_metadata(external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json"))
    assert _kinds("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap")[md.packet_size] == ("ouster_lidar", False)
    with_md = _kinds("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", md)
    assert with_md[md.packet_size] == ("ouster_lidar", True) and with_md[48] == ("ouster_imu", True)


def test_a_sensor_restart_is_an_interruption_not_a_loss():
    # two real captures years apart back to back: the device clock jumps, nothing was lost
    a = _velodyne_payloads("rust-lidar-utils/velodyne_vlp16.pcap")
    b = _velodyne_payloads("rust-lidar-utils/velodyne_example.pcap")
    t = VelodyneCounter()
    t.update(a)
    t.update(b)
    assert (t.count.lost, t.count.out_of_order, t.count.interruptions) == (0, 0, 1)
    # Ouster: the capture again with frame ids 500 frames (50 s) later, one packet missing
    md = load_metadata(external("rust-lidar-utils/ouster_example.json"))
    lidar = np.concatenate([b.payload for b in read_batches(external("rust-lidar-utils/ouster_example.pcap"))])
    later = lidar.copy()
    view = later.view(md.profile.packet_dtype(md.pixels_per_column, md.columns_per_packet))[:, 0]
    view["columns"]["frame_id"] += 500
    t = OusterCounter(md)
    t.update(lidar)
    t.update(np.delete(later, 50, axis=0))
    assert (t.count.out_of_order, t.count.interruptions, t.count.lost) == (0, 1, 1)


def test_hdl32e_timing_is_not_taken_for_vlp16_loss(tmp_path):
    """velodyne_vlp32.pcap is an HDL-32E (SOURCES.md: packets every 552-553 µs)."""
    from lidarpkt.core.packet import PacketBatch
    from lidarpkt.writers.mcap.writer import McapWriter
    from lidarpkt.writers.mcap.packets import PacketSink

    payload = _velodyne_payloads("rust-lidar-utils/velodyne_vlp32.pcap")
    vlp_timing = VelodyneCounter()
    vlp_timing.update(payload)
    assert vlp_timing.count.out_of_order > 0  # what a VLP-16 period would wrongly say
    w = McapWriter(tmp_path / "h.mcap")
    sink = PacketSink(w)
    sink.push(PacketBatch.from_payloads(payload, np.arange(len(payload)) * 553_000))
    sink.finish()
    w.close()
    assert (sink.lost, sink.out_of_order, sink.packets) == (0, 0, 91)
