"""``lidarpkt view --rerun``, end to end as a user runs it:

* ``--rerun web:0``: Rerun's web viewer (the build rerun-sdk carries) served by the view, opened in
  Debian's headless Chromium (Playwright for Python pointed at it, software WebGL), draws the cloud in
  its 3D panel; the screenshot is saved as ``rerun-web-viewer.png`` in the test's tmp folder;
* ``--rerun FILE.rrd``: a capture played, and a live sensor replayed over loopback UDP, recorded to a
  file that Rerun's own reader (its dataframe API) reads back with every frame and its points.

Every process started here (the view, the replay, the Playwright driver, Chromium) is ended, pass or
fail. Without Chromium or Playwright the screenshot test skips saying how to install them (in CI that
skip fails: ``.ci/run`` installs Chromium).
"""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np
import pytest

import lidarpkt
from test_view_foxglove_studio import CHROMIUM_ARGS, INSTALL, _chromium  # Debian's Chromium, software WebGL
from view_client import LidarpktProcess

rr = pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install '.[rerun]')")
pytest.importorskip("datafusion", reason="Rerun's dataframe API needs datafusion (pip install '.[test]')")

CANNED = Path(__file__).resolve().parents[2] / "lidarpkt" / "fixtures" / "canned"
BUDGET_S = 150  # from the page's start to the cloud drawn (the viewer's WebAssembly in software GL, a loaded machine)


def _read_rrd(path: Path):
    with rr.server.Server(datasets={"view": [str(path)]}) as server:
        client = server.client()
        dataset = client.get_dataset("view")
        return dataset.reader(index="frame").to_arrow_table()


def _check_recording(path: Path, frames: list, entity: str) -> None:
    """One entry per frame on the ``frame`` timeline, each with that frame's strongest-return points."""
    table = _read_rrd(path)
    ids = table.column("frame").to_pylist()
    positions = table.column(f"{entity}:Points3D:positions").to_pylist()
    got = {fid: len(p) for fid, p in zip(ids, positions) if p is not None}
    want = {}
    for f in frames:
        pts = f.points()
        want[f.frame_id] = int((pts["return_slot"] == 0).sum())
    assert got == want


def _panel_colour_fraction(png: bytes) -> float:
    """The share of strongly coloured pixels (max - min channel > 80) in the viewer's 3D panel: the block
    of rows, from the top, whose pixels are mostly its black background (the viewer's own panels are light;
    its range image, in colour, lies below the 3D panel)."""
    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)
    black = rgb.max(axis=2) < 40
    rows = black.mean(axis=1) > 0.3
    if not rows.any():
        return 0.0
    first = last = int(np.argmax(rows))
    while last + 1 < rows.size and rows[last + 1]:
        last += 1
    cols = np.flatnonzero(black[first:last + 1].mean(axis=0) > 0.3)
    panel = rgb[first:last + 1, cols.min():cols.max() + 1]
    return float((panel.max(axis=2) - panel.min(axis=2) > 80).mean())


@pytest.mark.timeout(400)
def test_rerun_web_viewer_served_by_the_view_draws_the_cloud(tmp_path):
    chromium = _chromium()
    sync_api = pytest.importorskip("playwright.sync_api", reason=f"Playwright for Python is not installed; {INSTALL}")
    shot = tmp_path / "rerun-web-viewer.png"
    with LidarpktProcess(tmp_path / "view.log", "view", str(CANNED / "os1-64-dual.pcap"), "--metadata",
                         str(CANNED / "os1-64-dual.json"), "--rerun", "web:0", "--loop", "--rate", "0.5",
                         ready="Rerun web viewer on http://", timeout=120) as view, \
            sync_api.sync_playwright() as playwright:
        import re

        url = re.search(r"Rerun web viewer on (http://\S+)", view.log.read_text()).group(1)
        assert "?url=rerun+http://localhost:" in url  # the page connects to the view's gRPC server by itself
        browser = playwright.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1000, "height": 700})
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            start = time.monotonic()
            page.goto(url, wait_until="commit")
            lit = 0.0
            try:
                page.locator("canvas").first.wait_for(timeout=BUDGET_S * 1000)
                while time.monotonic() - start < BUDGET_S:
                    lit = _panel_colour_fraction(page.screenshot(timeout=60_000))
                    if lit > 0.01:
                        break
                    time.sleep(1.0)
                elapsed = time.monotonic() - start
            finally:
                page.screenshot(path=str(shot), timeout=60_000)
        finally:
            browser.close()
        assert view.stop() == 0, view.log.read_text()
    assert not errors, errors
    # the OS1-64 scene (walls and ground rings around the sensor) coloured by range covers about a tenth of
    # the 3D panel at the viewer's default camera; the panel is otherwise black and grey grid lines
    assert lit > 0.01, f"the 3D panel stayed empty ({lit:.4f} coloured) after {elapsed:.0f} s; see {shot}"
    print(f"Rerun's web viewer drew the cloud {elapsed:.1f} s after the page's start; screenshot {shot}")


def test_view_records_a_capture_to_rrd(tmp_path):
    capture = CANNED / "vlp16-dual.pcap"
    out = tmp_path / "view.rrd"
    with LidarpktProcess(tmp_path / "view.log", "view", str(capture), "--rerun", str(out), "--rate", "5",
                         "--color", "reflectivity", ready="recording to") as view:
        # a file holds every frame once the capture has played: the view ends by itself, it serves nothing
        assert view.proc.wait(timeout=120) == 0, view.log.read_text()
    assert "still serving" not in view.log.read_text()
    assert [p.name for p in tmp_path.iterdir() if p.suffix in (".rrd", ".tmp")] == ["view.rrd"]
    _check_recording(out, list(lidarpkt.open(capture)), "/velodyne/points/last")


def test_view_records_a_live_sensor_to_rrd(tmp_path):
    from test_replay_record import _free_ports as free_udp_ports

    capture = CANNED / "vlp16-strongest.pcap"
    frames = list(lidarpkt.open(capture))
    out = tmp_path / "live.rrd"
    data, position = free_udp_ports(2)
    with LidarpktProcess(tmp_path / "view.log", "view", "--rerun", str(out), "--bind", "127.0.0.1",
                         "--port", str(data), "--port", str(position), ready="listening on") as view:
        with LidarpktProcess(tmp_path / "replay.log", "replay", str(capture), "--rate", "2", "--to",
                             f"127.0.0.1:{data}", "--port-map", f"8308:{position}") as replay:
            assert replay.proc.wait(timeout=120) == 0, replay.log.read_text()
        time.sleep(1.0)  # the last datagrams through the receive path
        assert view.stop() == 0, view.log.read_text()  # the last frame, still being assembled, is published
    # live frames get their hour from the host clock: the frame ids and point counts are the capture's
    _check_recording(out, frames, "/velodyne/points/strongest")


def test_bad_rerun_target_is_one_line_and_exit_2(tmp_path, capsys):
    from lidarpkt.cli import main

    assert main(["view", str(CANNED / "vlp16-dual.pcap"), "--rerun", "web:http", "--duration", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("--rerun web:http: give web or web:PORT (PORT 0-65534, 0: any free port)")
    assert main(["view", str(CANNED / "vlp16-dual.pcap"), "--rerun", str(tmp_path / "no" / "x.rrd")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
    assert main(["view", str(CANNED / "vlp16-dual.pcap"), "--rerun", "/proc/x.rrd"]) == 2  # a folder not writable
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("--rerun /proc/x.rrd: cannot write in /proc; choose a writable folder")
    import socket

    with socket.socket() as taken:  # the gRPC port (web:PORT's PORT + 1) held by another server
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["view", str(CANNED / "vlp16-dual.pcap"), "--rerun", f"web:{port - 1}", "--duration", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is in use" in err[0] and err[0].endswith("give web:PORT with a free PORT and PORT + 1, or web:0"), err
