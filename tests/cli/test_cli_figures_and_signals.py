"""Issue 14 items 7 and 8: replay stopped by SIGTERM prints its summary; the figures' labels fit.

The figures are drawn from VeloView's real 20 Hz capture and checked by their rendered text
extents (matplotlib's own layout), not by pixels.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import end_process, external, start_process

REPO = Path(__file__).resolve().parents[2]
VLP20 = "veloview/vlp-16-test-90deg-1-50-frames.pcap"


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_replay_stopped_by_sigterm_prints_its_summary_and_exits_0():
    port = _free_port()
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", port))
    sink.settimeout(30)
    proc = start_process([sys.executable, "-m", "lidarpkt", "replay", str(external(VLP20)), "--to",
                          f"127.0.0.1:{port}", "--loop"], stderr=subprocess.PIPE, text=True, cwd=REPO,
                         env=dict(os.environ, PYTHONPATH=str(REPO)))
    try:
        sink.recv(2048)  # it is sending
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        end_process(proc)
        sink.close()
    assert proc.returncode == 0, err  # was 143, without a summary
    assert "lidarpkt replay: interrupted; sent" in err and "Traceback" not in err


@pytest.fixture(scope="module")
def stack():
    pytest.importorskip("matplotlib", reason="figures need the `plot` extra")
    from lidarpkt.analysis.stack import load_stack

    return load_stack(external(VLP20), frames=(0, 20))


def _draw(fig) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)  # the figures are made without pyplot: give them a canvas to lay out on
    fig.canvas.draw()


def _inside(fig, artist) -> bool:
    renderer = fig.canvas.get_renderer()
    box = artist.get_window_extent(renderer)
    page = fig.bbox
    return box.x0 >= page.x0 - 1 and box.x1 <= page.x1 + 1 and box.y0 >= page.y0 - 1 and box.y1 <= page.y1 + 1


def test_multireturn_map_colour_bar_labels_are_not_cut_off(stack):
    from lidarpkt.analysis import plots
    from lidarpkt.analysis.multireturn import multireturn_map

    fig = plots.plot_multireturn_map(multireturn_map(stack), stack, 0, "VeloView")
    _draw(fig)
    def shown(ax):  # tick labels inside the axis' limits (the others are never drawn)
        lo, hi = sorted(ax.get_ylim())
        return [t for t in ax.get_yticklabels() if lo <= t.get_position()[1] <= hi]

    texts = [t for ax in fig.axes for t in shown(ax) + [ax.yaxis.label] if t.get_text()]
    # the old label "flagged & multi" read as cut off: the words are whole now, and inside the figure
    assert any(t.get_text().replace("\n", " ") == "flagged & multi-return" for t in texts)
    cut = [t.get_text() for t in texts if not _inside(fig, t)]
    assert not cut, cut


def test_range_image_pixel_labels_do_not_overlap_and_grey_is_explained(stack):
    from lidarpkt.analysis import plots

    # (7, 449), (7, 470) and (8, 480): three marks within 31 columns of 900, on neighbouring rows
    fig = plots.plot_range_image(stack, 0, 0, [(7, 449), (7, 470), (8, 480), (2, 890)], "VeloView")
    _draw(fig)
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    boxes = [t.get_window_extent(renderer) for t in ax.texts]
    assert len(boxes) == 4
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            assert not boxes[i].overlaps(boxes[j]), (ax.texts[i].get_text(), ax.texts[j].get_text())
    assert all(_inside(fig, t) for t in ax.texts)
    colour_bar = fig.axes[1]
    assert "grey: no sample" in colour_bar.yaxis.label.get_text() and _inside(fig, colour_bar.yaxis.label)
