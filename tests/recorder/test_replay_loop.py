"""``replay --loop`` sends every round from one source address (receivers see one sensor, not one per
round), and stops on Ctrl-C even when started with SIGINT ignored (as ``&`` in a script starts it)."""

from __future__ import annotations

import os
import signal
import socket
import sys
import time
from pathlib import Path

from conftest import external, start_process

REPO = Path(__file__).resolve().parents[2]
VLP10 = "rust-lidar-utils/velodyne_example.pcap"  # 84 data packets


def test_loop_keeps_its_source_address_and_stops_on_ctrl_c_with_sigint_ignored():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.2)
    port = rx.getsockname()[1]
    argv = [sys.executable, "-m", "lidarpkt", "replay", str(external(VLP10)), "--to", f"127.0.0.1:{port}", "--loop",
            "--rate", "20"]
    # SIGINT ignored when the process starts, as a shell's ``&`` leaves it; exec keeps the disposition
    launcher = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_IGN); "
                f"os.execv(sys.executable, {argv!r})")
    proc = start_process([sys.executable, "-c", launcher], cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)),
                         stderr=__import__("subprocess").PIPE, text=True)
    sources, packets = set(), 0
    deadline = time.monotonic() + 60
    try:
        while packets < 3 * 84 and time.monotonic() < deadline:  # three rounds at least
            try:
                _, src = rx.recvfrom(65535)
            except socket.timeout:
                continue
            sources.add(src)
            packets += 1
        assert packets >= 3 * 84, "the replay did not loop"
        assert len(sources) == 1, sources
        os.kill(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    finally:
        rx.close()
    assert proc.returncode == 0, err
    assert "interrupted" in err and "Traceback" not in err
