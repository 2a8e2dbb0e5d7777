"""The serial GPS path through a real pseudo-terminal pair: sentences in, checksums verified,
written to MCAP by ``lidarpkt record --gps``."""

from __future__ import annotations

import json
import os
import signal
import time
import tty

import pytest

from lidarpkt.errors import NMEAError, SerialPortError
from lidarpkt.core import nmea
from lidarpkt.recorder.gps import GpsReader, verify_sentence
from test_replay_record import Recorder

# The classic NMEA 0183 example sentences (GGA, RMC, GSA, VTG) with their published checksums;
# the first test checks them against an independent XOR.
GOOD = [
    "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47",
    "$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A",
    "$GPGSA,A,3,04,05,,09,12,,,24,,,,,2.5,1.3,2.1*39",
    "$GPVTG,054.7,T,034.4,M,005.5,N,010.2,K*48",
]
BAD = [
    "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*48",  # checksum off by one
    "$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W",  # no checksum
    "garbage line without a dollar",
]


def _xor(body: str) -> int:
    v = 0
    for c in body:
        v ^= ord(c)
    return v


def test_the_published_example_checksums_verify():
    for s in GOOD:
        body, _, given = s[1:].rpartition("*")
        assert _xor(body) == int(given, 16)
        assert verify_sentence(s + "\r\n") == s
    for s in BAD:
        with pytest.raises(NMEAError):
            verify_sentence(s)
    # the same verification as the VLP-16 position packets' NMEA parser
    fix = nmea.parse_nmea(GOOD[1])
    assert fix.valid and fix.date == (1994, 3, 23)


def _pty():
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo, no line discipline rewriting CR/LF
    return master, slave, os.ttyname(slave)


def _wait_until_read(slave: int, timeout_s: float = 60.0) -> None:
    """Until the recorder has read every byte written to the pty (none waits on its side), at most
    ``timeout_s``: a condition, not a guess of how long a loaded machine takes."""
    import fcntl
    import termios

    deadline = time.monotonic() + timeout_s
    while int.from_bytes(fcntl.ioctl(slave, termios.FIONREAD, b"\0\0\0\0"), "little"):
        assert time.monotonic() < deadline, "the recorder did not read the GPS sentences"
        time.sleep(0.02)


def test_gps_reader_over_a_real_pty_keeps_good_sentences_and_counts_bad_ones():
    master, slave, name = _pty()
    try:
        gps = GpsReader(name, 9600)
        gps.start()
        stream = "".join(s + "\r\n" for s in [GOOD[0], BAD[0], GOOD[1], BAD[1], GOOD[2], BAD[2], GOOD[3]])
        before = time.time_ns()
        # in pieces that cut sentences in the middle, as a UART delivers them
        data = stream.encode()
        for i in range(0, len(data), 37):
            os.write(master, data[i:i + 37])
            time.sleep(0.01)
        got = []
        deadline = time.monotonic() + 60  # a generous bound: the loop ends on the condition
        while len(got) < len(GOOD) and time.monotonic() < deadline:
            got += gps.drain()
            time.sleep(0.02)
        gps.close()
    finally:
        os.close(master)
        os.close(slave)
    assert [s for _, s in got] == GOOD
    assert all(before <= t <= time.time_ns() for t, _ in got)
    assert gps.sentences == 4 and gps.bad == 3


def test_a_port_that_does_not_exist_is_a_clear_error(tmp_path):
    with pytest.raises(SerialPortError, match="cannot open GPS serial port"):
        GpsReader(str(tmp_path / "ttyNOPE"), 9600)


def test_record_writes_gps_sentences_into_the_mcap(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    master, slave, name = _pty()
    try:
        with Recorder(tmp_path, [port], "--gps", name, "--baud", "115200", "-q") as rec:
            for s in [GOOD[0], BAD[0], GOOD[1], GOOD[3]]:
                os.write(master, (s + "\r\n").encode())
                time.sleep(0.05)
            _wait_until_read(slave)
            assert rec.stop(signal.SIGINT) == 0, rec.log.read_text()  # Ctrl-C: a clean stop
    finally:
        os.close(master)
        os.close(slave)
    out, report = rec.out, rec.report
    summary = json.loads(report.read_text())
    assert summary["gps_sentences"] == 3 and summary["gps_bad_checksum"] == 1 and summary["stopped_by"] == "SIGINT"
    with open(out, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        msgs = [(s.name, c.topic, m.log_time, d) for s, c, m, d in reader.iter_decoded_messages()]
    assert [d.sentence for _, _, _, d in msgs] == [GOOD[0], GOOD[1], GOOD[3]]
    assert {(n, t) for n, t, _, _ in msgs} == {("nmea_msgs/msg/Sentence", "/gps/nmea_sentence")}
    stamps = [d.header.stamp.sec * 10**9 + d.header.stamp.nanosec for _, _, _, d in msgs]
    # header.stamp = the GPS's UTC: GGA 12:35:19 (date from the host), RMC 1994-03-23 12:35:19; VTG: host
    assert stamps[0] % 86_400_000_000_000 == (12 * 3600 + 35 * 60 + 19) * 10**9
    assert abs(stamps[0] - msgs[0][2]) <= 43_200 * 10**9
    assert stamps[1] == 764_426_119 * 10**9  # calendar.timegm((1994, 3, 23, 12, 35, 19))
    assert stamps[2] == msgs[2][2]
