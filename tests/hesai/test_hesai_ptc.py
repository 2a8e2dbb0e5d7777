"""Hesai PTC over real TCP sockets: the calibration read from a sensor (here lidarpkt's own PTC server,
then ``lidarpkt replay --ptc``), errors named, and a replayed bag decoded live with the calibration it served."""

from __future__ import annotations

import glob
import socket
import struct
import subprocess
import sys
import threading
import warnings

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import CalibrationError
from lidarpkt.vendors.hesai import HesaiDecoder, load_calibration
from lidarpkt.vendors.hesai.ptc import GET_LIDAR_CALIBRATION, PtcError, PtcServer, fetch_calibration, ptc_request
from lidarpkt.core.packet import PacketBatch


def test_calibration_read_over_ptc_is_the_file(ext):
    csv = ext("nebula/hesai/PandarQT128.csv")
    with PtcServer({GET_LIDAR_CALIBRATION: csv.read_bytes()}) as server:
        cal = fetch_calibration("127.0.0.1", port=server.port)
        with pytest.raises(PtcError, match="error 5 \\(unsupported command\\)"):
            ptc_request("127.0.0.1", 0x09, port=server.port)
    want = load_calibration(csv)
    assert np.array_equal(cal.elevation_deg, want.elevation_deg) and cal.channels == 128
    assert np.array_equal(cal.azimuth_offset_deg, want.azimuth_offset_deg)


def _one_shot_server(reply: bytes) -> tuple[socket.socket, threading.Thread]:
    sock = socket.create_server(("127.0.0.1", 0))

    def serve():
        conn, _ = sock.accept()
        with conn:
            conn.recv(64)
            conn.sendall(reply)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    return sock, t


@pytest.mark.parametrize("reply, why", [
    (b"HTTP/1.1 200 OK\r\n\r\n", "no PTC answer"),
    (struct.pack(">BBBBI", 0x47, 0x74, 0x05, 0, 1 << 30), "1073741824 bytes"),
    (struct.pack(">BBBBI", 0x47, 0x74, 0x05, 0, 100) + b"1,2", "closed after 3 of 100"),
    (struct.pack(">BBBBI", 0x47, 0x74, 0x05, 0, 4) + b"\xff\xfe\x00\x01", "utf-8"),
])
def test_a_bad_answer_is_one_clear_error(reply, why):
    sock, t = _one_shot_server(reply)
    try:
        with pytest.raises(CalibrationError, match=why) as info:
            fetch_calibration("127.0.0.1", port=sock.getsockname()[1], timeout_s=2)
        assert "127.0.0.1" in str(info.value) and info.value.__cause__ is not None
    finally:
        t.join(timeout=2)
        sock.close()


def test_no_sensor_is_one_clear_error():
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()  # nothing listens there
    with pytest.raises(CalibrationError, match=f"127.0.0.1:{port}"):
        fetch_calibration("127.0.0.1", port=port, timeout_s=1)


def test_replay_serves_the_calibration_and_the_packets_decode_live(ext):
    """``lidarpkt replay BAG --ptc --calibration``: a client reads the calibration over PTC, then the UDP
    stream, and its frames are those of ``lidarpkt.open`` on the bag."""
    bag = glob.glob(str(ext("nebula/hesai/xt16")) + "/*/")[0]
    csv = ext("nebula/hesai/PandarXT16.csv")
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5)
    proc = subprocess.Popen([sys.executable, "-m", "lidarpkt", "replay", bag, "--to", f"127.0.0.1:{rx.getsockname()[1]}",
                             "--max", "--ptc", "127.0.0.1:0", "--calibration", str(csv),
                             "--start-after-fetch", "0.2"], stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline()
        assert "serving the Hesai calibration over PTC at 127.0.0.1:" in line, line
        cal = fetch_calibration("127.0.0.1", port=int(line.rsplit(":", 1)[1]))
        payloads = []
        while len(payloads) < 1626:
            try:
                payloads.append(rx.recv(2048))
            except TimeoutError:
                break
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()
        rx.close()
    assert len(payloads) == 1626 and {len(p) for p in payloads} == {568}
    dec = HesaiDecoder(calibration=cal)
    arr = np.frombuffer(b"".join(payloads), np.uint8).reshape(-1, 568)
    live = dec.push(PacketBatch.from_payloads(arr, np.arange(len(arr), dtype=np.int64) * 200_000)) + dec.finish()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stored = list(lidarpkt.open(bag, metadata=csv))
    assert len(live) == len(stored)
    for a, b in zip(live, stored):
        assert np.array_equal(a.range_mm, b.range_mm) and np.array_equal(a.xyz(), b.xyz())
