"""The Ouster HTTP API, both sides (lidarpkt.vendors.ouster.sensor_http), on loopback with real sockets:
``replay --http`` serves the metadata at /api/v1/sensor/metadata exactly as given; a sensor that
does not answer (nothing listening, a wrong path, not JSON) is a one-line error naming the host and
the URL tried, exit 2, and no output file. ``--metadata`` is repeatable in record and replay."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
import threading

import pytest

from lidarpkt.errors import SensorConnectionError, UsageError
from lidarpkt.vendors.ouster.sensor_http import MetadataHttpServer, fetch_metadata, fetch_metadata_text, parse_sensor
from test_view_capture import CANNED
from test_view_live import free_udp_ports
from view_client import LidarpktProcess

REPO = CANNED.parents[1]


def closed_tcp_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_served_metadata_is_byte_for_byte_and_parses():
    text = (CANNED / "os1-64-legacy.json").read_text()
    with MetadataHttpServer(text) as server:
        with urllib.request.urlopen(f"http://127.0.0.1:{server.port}/api/v1/sensor/metadata", timeout=10) as r:
            assert r.read().decode() == text
            assert r.headers["Content-Type"] == "application/json"
        assert fetch_metadata_text("127.0.0.1", server.port) == text
        md = fetch_metadata("127.0.0.1", server.port)
        assert md.raw == json.loads(text) and md.columns_per_frame == 1024
        with pytest.raises(urllib.error.HTTPError):
            urllib.request.urlopen(f"http://127.0.0.1:{server.port}/api/v1/other", timeout=10)
    with pytest.raises(SensorConnectionError, match="no answer"):  # closed: the port is released
        fetch_metadata_text("127.0.0.1", server.port, timeout_s=2)


def test_no_sensor_names_host_and_url():
    port = closed_tcp_port()
    with pytest.raises(SensorConnectionError) as info:
        fetch_metadata_text("127.0.0.1", port, timeout_s=2)
    msg = str(info.value)
    assert f"--sensor 127.0.0.1:{port}" in msg and f"http://127.0.0.1:{port}/api/v1/sensor/metadata" in msg
    assert "--metadata" in msg


def test_a_server_that_is_no_sensor():
    class NotASensor(BaseHTTPRequestHandler):
        def do_GET(self):
            body = b"<html>router login</html>" if self.path.endswith("metadata") else b""
            self.send_response(200 if body else 404)
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *a):
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), NotASensor)
    t = threading.Thread(target=httpd.serve_forever, daemon=True)
    t.start()
    try:
        with pytest.raises(SensorConnectionError, match="did not return JSON"):
            fetch_metadata_text("127.0.0.1", httpd.server_address[1])
    finally:
        httpd.shutdown()
        httpd.server_close()


def test_a_sensor_that_never_answers_times_out():
    listener = socket.socket()  # accepts the connection (backlog) but never answers
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    try:
        with pytest.raises(SensorConnectionError, match=r"within 0\.5 s"):
            fetch_metadata_text("127.0.0.1", listener.getsockname()[1], timeout_s=0.5)
    finally:
        listener.close()


@pytest.mark.parametrize("text, expected", [("10.5.6.101", ("10.5.6.101", 80)),
                                            ("os-1.local:8080", ("os-1.local", 8080)),
                                            ("[fe80::1]:80", ("fe80::1", 80))])
def test_parse_sensor(text, expected):
    assert parse_sensor(text) == expected


@pytest.mark.parametrize("text", ["host:0", "host:x", ":80", "host:70000"])
def test_parse_sensor_rejects(text):
    with pytest.raises(UsageError, match="--sensor"):
        parse_sensor(text)


@pytest.mark.parametrize("verb", ["record", "view"])
def test_cli_sensor_not_answering_is_one_line_exit_2(tmp_path, verb):
    port = closed_tcp_port()
    out = tmp_path / "out.mcap"
    extra = ["-o", str(out)] if verb == "record" else ["--ws", "127.0.0.1:0"]
    r = subprocess.run([sys.executable, "-m", "lidarpkt", verb, "--sensor", f"127.0.0.1:{port}", "--port",
                        str(free_udp_ports(1)[0]), *extra], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"lidarpkt: error: --sensor 127.0.0.1:{port}: no answer to GET "
                                                   f"http://127.0.0.1:{port}/api/v1/sensor/metadata"), r.stderr
    assert not out.exists()


def test_replay_http_needs_metadata(tmp_path):
    r = subprocess.run([sys.executable, "-m", "lidarpkt", "replay", str(CANNED / "vlp16-dual.pcap"), "--to",
                        f"127.0.0.1:{free_udp_ports(1)[0]}", "--http", "127.0.0.1:0"],
                       capture_output=True, text=True, timeout=60, cwd=REPO)
    assert r.returncode == 2
    assert r.stderr.strip() == ("lidarpkt: error: --http 127.0.0.1:0: there is no Ouster metadata to serve; "
                                "give --metadata M.json")


def test_record_takes_metadata_once_per_sensor(tmp_path):
    """Two --metadata: both written to /ouster/metadata and as sensor records; each sensor's ports listened on."""
    from test_view_record import read_mcap

    md1 = json.loads((CANNED / "os1-64-legacy.json").read_text())
    md2 = json.loads((CANNED / "os1-64-dual.json").read_text())
    ports = free_udp_ports(4)
    for md, (lidar, imu) in ((md1, ports[:2]), (md2, ports[2:])):
        cfg = md.setdefault("config_params", {})
        cfg["udp_port_lidar"], cfg["udp_port_imu"] = lidar, imu
    (tmp_path / "a.json").write_text(json.dumps(md1))
    (tmp_path / "b.json").write_text(json.dumps(md2))
    out = tmp_path / "two.mcap"
    with LidarpktProcess(tmp_path / "rec.log", "record", "--bind", "127.0.0.1", "--metadata", str(tmp_path / "a.json"),
                         "--metadata", str(tmp_path / "b.json"), "-o", str(out), ready="listening on") as rec:
        assert all(str(p) in rec.log.read_text() for p in ports), rec.log.read_text()
        assert rec.stop() == 0, rec.log.read_text()
    served = [json.loads(m.data) for t, _, m in read_mcap(out) if t == "/ouster/metadata"]
    assert served == [md1, md2]


def test_replay_takes_metadata_once_per_sensor(tmp_path):
    """With two --metadata, the non-legacy stream (known only from its metadata) still goes to --to."""
    from lidarpkt.recorder.replay import read_capture

    capture = CANNED / "os1-64-dual.pcap"
    from lidarpkt.vendors.ouster import load_metadata

    imu = load_metadata(str(CANNED / "os1-64-dual.json")).imu_port
    lidar_size = {len(p.payload) for p in read_capture(str(capture))} - {48}
    expected = sum(1 for p in read_capture(str(capture)) if len(p.payload) in lidar_size)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 16 << 20)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(2)
    imu_port = free_udp_ports(1)[0]
    try:
        r = subprocess.run([sys.executable, "-m", "lidarpkt", "replay", str(capture), "--max", "--to",
                            f"127.0.0.1:{sock.getsockname()[1]}", "--port-map", f"{imu}:{imu_port}",
                            "--metadata", str(CANNED / "os1-64-legacy.json"),
                            "--metadata", str(CANNED / "os1-64-dual.json")],
                           capture_output=True, text=True, timeout=60, cwd=REPO)
        assert r.returncode == 0, r.stderr
        got = 0
        try:
            while True:
                data = sock.recv(65535)
                assert len(data) in lidar_size
                got += 1
        except TimeoutError:
            pass
    finally:
        sock.close()
    assert got == expected and "no known stream" not in r.stderr
