"""Live: a Pandar stream replayed over UDP to ``lidarpkt record`` (a real subprocess): counted as a Hesai
stream (packets, losses from its UDP sequence, rotations), kept byte for byte, and read back into the
frames of the bag."""

from __future__ import annotations

import glob
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import lidarpkt
from lidarpkt.recorder.replay import read_capture, replay

REPO = Path(__file__).resolve().parents[2]


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_record_counts_a_pandar_stream_and_keeps_it(ext, tmp_path):
    bag = glob.glob(str(ext("nebula/hesai/xt32")) + "/*/")[0]
    port = _free_udp_port()
    out, report, log = tmp_path / "rec.mcap", tmp_path / "rec.json", tmp_path / "rec.log"
    cmd = [sys.executable, "-m", "lidarpkt", "record", "--bind", "127.0.0.1", "--port", str(port), "-o", str(out),
           "--report", str(report)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log.open("w"), cwd=REPO, env=dict(os.environ))
    try:
        deadline = time.monotonic() + 30
        while "listening on" not in log.read_text():
            assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.05)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sent = replay(read_capture(bag), "127.0.0.1", port, rate=None)
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert sent.packets == 2000
    doc = json.loads(report.read_text())
    (stream,) = [s for s in doc["streams"] if s["kind"] == "hesai_data"]
    assert stream["packets"] == 2000 and stream["lost"] == 0 and stream["out_of_order"] == 0
    assert stream["frames"] == 4 and doc["frames"] == 4  # the azimuth wraps four times in the bag
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        live = list(lidarpkt.open(out))
        stored = list(lidarpkt.open(bag))
    assert [f.shape for f in live] == [f.shape for f in stored]
    assert all(np.array_equal(a.range_mm, b.range_mm) for a, b in zip(live, stored))
