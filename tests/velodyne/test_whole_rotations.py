"""Issue 17 §1: every whole rotation counts. ``partial`` means columns of the rotation are missing.

A capture of exactly N rotations, beginning one firing after the cut angle and ending one firing
before it, gives N whole frames (VLP-16 through the generator and the encoder; Ouster through the
generated OS1-64 captures, whole in measurement ids). Frames that really miss columns at the
start or the end stay partial.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt import fixtures
import lidarpkt
from lidarpkt.fixtures import vlp16
from lidarpkt.vendors.ouster import OusterDecoder, load_metadata
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.pcap_reader import read_batches

ROTATIONS = 50


@pytest.fixture(scope="module")
def fifty(tmp_path_factory):
    """{mode: pcap} of exactly 50 rotations, first firing at 0.1°, last at 359.9°."""
    out = tmp_path_factory.mktemp("rotations")
    return {m: vlp16.write_vlp16_rotations(out / f"{m}.pcap", ROTATIONS, mode=m) for m in ("strongest", "dual")}


@pytest.mark.parametrize("mode", ["strongest", "dual"])
@pytest.mark.parametrize("cut_on_block", [False, True])
def test_fifty_whole_rotations_give_fifty_whole_frames(fifty, mode, cut_on_block):
    frames = list(lidarpkt.open(fifty[mode], cut_on_block=cut_on_block))
    assert len(frames) == ROTATIONS
    assert not any(f.partial for f in frames)
    assert all(f.shape[2] == 1800 and f.column_valid.all() for f in frames)
    assert frames[0].azimuth_deg[0] == pytest.approx(0.1) and frames[-1].azimuth_deg[-1] == pytest.approx(359.9)
    # include_partial=False (the analysis' default selection) keeps all fifty
    assert len(list(lidarpkt.open(fifty[mode], include_partial=False))) == ROTATIONS


def test_the_analysis_stacks_fifty_frames(fifty):
    from lidarpkt.analysis.stack import load_stack

    stack = load_stack(fifty["strongest"])
    assert stack.range_mm.shape[0] == ROTATIONS


@pytest.mark.parametrize("drop", ["first", "last", "both"])
def test_rotations_missing_columns_at_the_ends_stay_partial(tmp_path, drop):
    packets = {"first": slice(1, None), "last": slice(None, -1), "both": slice(1, -1)}[drop]
    pcap = vlp16.write_vlp16_rotations(tmp_path / "cut.pcap", 3, packets=packets)
    frames = list(lidarpkt.open(pcap))
    assert len(frames) == 3
    assert [f.partial for f in frames] == [drop in ("first", "both"), False, drop in ("last", "both")]


def test_one_missing_column_at_the_start_is_partial(tmp_path):
    # the first firing at 0.3°: the one at 0.1° is missing
    frames = list(lidarpkt.open(vlp16.write_vlp16_rotations(tmp_path / "a.pcap", 2, first_cdeg=30)))
    assert frames[0].partial
    # the first firing at 0.19°: the one before it would have been at −0.01°, another rotation
    frames = list(lidarpkt.open(vlp16.write_vlp16_rotations(tmp_path / "b.pcap", 2, first_cdeg=19)))
    assert not frames[0].partial


def test_cut_angle_moves_the_ends(fifty):
    # cut at 90°: the capture begins and ends a quarter turn away from it, so both ends are partial
    frames = list(lidarpkt.open(fifty["strongest"], cut_angle_deg=90))
    assert len(frames) == ROTATIONS + 1
    assert frames[0].partial and frames[-1].partial and not any(f.partial for f in frames[1:-1])


def _ouster_batches(name: str):
    pcap = fixtures.canned(name)
    md = load_metadata(fixtures.metadata_path(pcap))
    batch = PacketBatch.concatenate([b for b in read_batches(pcap) if b.payload_size == md.packet_size])
    return md, batch


@pytest.mark.parametrize("name", ["os1-64-legacy", "os1-64-dual"])
def test_ouster_whole_frames_are_whole_and_cut_ones_partial(name):
    md, batch = _ouster_batches(name)
    per_frame = md.columns_per_frame // md.columns_per_packet
    n_frames = len(batch) // per_frame
    assert n_frames * per_frame == len(batch)

    def decode(rows: slice) -> list:
        dec = OusterDecoder(md)
        sub = PacketBatch(batch.src, batch.dst, batch.timestamp_ns[rows], batch.payload[rows], batch.index[rows])
        return dec.push(sub) + dec.finish()

    whole = decode(slice(None))
    assert len(whole) == n_frames and not any(f.partial for f in whole)
    assert all(np.array_equal(f.measurement_id, np.arange(md.columns_per_frame)) for f in whole)
    cut = decode(slice(1, -1))
    assert [f.partial for f in cut] == [True] + [False] * (n_frames - 2) + [True]
