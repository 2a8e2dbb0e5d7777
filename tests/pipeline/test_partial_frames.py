"""``Frame.partial`` is True for every frame missing columns of its rotation, for every vendor, on real
captures with a stretch of packets cut out (the same rule for all: :func:`lidarpkt.core.rotation.rotation_is_whole`,
and Ouster's column window). The cut captures are made from the real packets: every packet of the capture
but a stretch, written as a pcap (:class:`~lidarpkt.writers.pcap.PcapBatchWriter`)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import lidarpkt
from lidarpkt.core.packet import Endpoint
from lidarpkt.vendors import registry
from lidarpkt.writers.pcap import PcapBatchWriter

from conftest import external

HESAI = "nebula/hesai/"
# case: (capture, sensor file, first packet cut, packets cut): the stretch lies inside a rotation
CASES = {
    "velodyne-vlp16-20hz": ("veloview/vlp-16-test-90deg-1-50-frames.pcap", None, 500, 15),
    "velodyne-vlp16-dual": ("nebula/vlp16/1673400471837873222", None, 200, 20),
    "velodyne-vls128": ("nebula/vls128/1614315746471294674", None, 1000, 100),
    "ouster-os0-128": ("ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json",
                       30, 4),
    "ouster-legacy": ("rust-lidar-utils/ouster_example.pcap", "rust-lidar-utils/ouster_example.json", 50, 3),
    "hesai-xt32": (HESAI + "xt32/1673400677802009732", HESAI + "PandarXT32.csv", 400, 30),
    "hesai-40p": (HESAI + "40p/1673400149412331409", HESAI + "Pandar40P.csv", 500, 40),
    "hesai-qt64": (HESAI + "qt64/1673401195788312575", HESAI + "PandarQT64.csv", 150, 20),
    "robosense-helios": ("nebula/robosense/helios16p/rosbag2_2023_08_03-11_02_46", None, 300, 15),
}


def _cut(src, dst, first: int, count: int) -> None:
    """Write every packet of ``src`` but those of ordinal ``first`` … ``first + count - 1`` to the pcap ``dst``."""
    cut = 0
    stand_in = Endpoint("192.168.1.201", 2368), Endpoint("192.168.1.100", 2368)  # a bag records no addresses
    source = registry.open_packets(src)
    with PcapBatchWriter(dst, mtu=None) as out:
        for batch in source.batches():
            gone = (batch.index >= first) & (batch.index < first + count)
            cut += int(gone.sum())
            out.write(batch.select(~gone), *stand_in)
    assert cut == count


def _frames(path, metadata) -> list:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the losses are said once; here they are what is tested
        return list(lidarpkt.open(path, metadata=None if metadata is None else str(external(metadata))))


@pytest.mark.parametrize("case", list(CASES))
def test_a_frame_that_lost_packets_is_partial_and_the_others_are_unchanged(case, tmp_path):
    capture, metadata, first, count = CASES[case]
    cut = tmp_path / "cut.pcap"
    _cut(external(capture), cut, first, count)
    whole = _frames(external(capture), metadata)
    frames = _frames(cut, metadata)
    # a frame of the cut capture that is not one of the whole capture's (same first column time, same
    # columns) is one the cut fell into: it must say it is partial
    own = {(int(f.column_timestamp_ns[f.column_valid][0]), f.range_mm.shape[-1], int(f.column_valid.sum())): f
           for f in whole if f.column_valid.any()}
    touched = []
    for frame in frames:
        if not frame.column_valid.any():
            continue
        key = (int(frame.column_timestamp_ns[frame.column_valid][0]), frame.range_mm.shape[-1],
               int(frame.column_valid.sum()))
        if key in own:
            assert frame.partial == own[key].partial, (case, frame.frame_id)
            continue
        touched.append(frame)
        assert frame.partial, (case, frame.frame_id, "columns lost inside, but partial is False")
    assert touched, (case, "the cut fell in no frame")
    # and a complete rotation of the capture is whole: the rule does not flag every frame
    assert any(not f.partial for f in whole), case


def test_a_velodyne_frame_with_lost_columns_says_so_in_column_valid_and_counters(tmp_path):
    cut = tmp_path / "cut.pcap"
    _cut(external(CASES["velodyne-vlp16-20hz"][0]), cut, 500, 15)
    lossy = [f for f in _frames(cut, None) if f.counters.lost_packets]
    assert lossy and all(f.partial and not f.column_valid.all() for f in lossy)
    assert sum(int((~f.column_valid).sum()) for f in lossy) >= 12 * 24  # 24 firing sequences a data packet (and a few position packets were cut)


def test_hesai_xt32m_frames_missing_most_of_a_rotation_are_partial():
    frames = _frames(external(HESAI + "xt32m/1660893203042895158"), HESAI + "PandarXT32M.csv")
    for f in frames:
        span_cdeg = np.diff(np.round(f.azimuth_deg * 100)) % 36000
        if f.counters.lost_packets or (span_cdeg.size and span_cdeg.max() > 2 * np.median(span_cdeg)):
            assert f.partial, f.frame_id
    assert sum(f.partial for f in frames) >= 4


def test_a_hesai_frame_with_lost_packets_holds_their_columns_as_invalid(tmp_path):
    """Hesai as Velodyne: the columns of lost packets are in the frame, invalid (no returns), so that the frame
    has the columns of its rotation; its points are those of the packets that arrived."""
    capture, metadata, first, count = CASES["hesai-xt32"]
    cut = tmp_path / "cut.pcap"
    _cut(external(capture), cut, first, count)
    whole = {int(f.column_timestamp_ns[0]): f for f in _frames(external(capture), metadata)}
    lossy = [f for f in _frames(cut, metadata) if f.counters.lost_packets]
    assert lossy
    for f in lossy:
        blocks = f.column_valid.size - int(f.column_valid.sum())
        assert f.partial and blocks > 0 and blocks % f.counters.lost_packets == 0  # whole packets' columns
        assert not f.range_mm[..., ~f.column_valid].any()
        same = whole.get(int(f.column_timestamp_ns[0]))
        if same is not None:  # the whole capture's frame: same width, its columns where packets arrived
            assert same.column_valid.size == f.column_valid.size
            assert np.array_equal(same.range_mm[..., f.column_valid], f.range_mm[..., f.column_valid])
            assert np.allclose(same.azimuth_deg, f.azimuth_deg, atol=0.02)  # interpolated where lost
