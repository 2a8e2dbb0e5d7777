"""Bad RoboSense input: random bytes under valid headers, hostile copies of the bag (flipped bytes, cut
packets, a DIFOP with nonsense angles, lost, repeated, reordered and time-corrupted packets, a restart).
Every case gives counted skips or one lidarpkt error, never another exception; loss counts stay
physical (never more than the capture time holds), and good packets are never dropped."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from robosense_bag import CSV, all_packets, batches
from conftest import external
from lidarpkt.core.packet import PacketBatch
from lidarpkt.errors import CalibrationError, LidarpktError
from lidarpkt.vendors.robosense import MODELS, PacketCounter, RobosenseDecoder, encode_difop
from lidarpkt.vendors.robosense import packet as P

PERIOD_NS = 12 * 55560  # an RS-Helios single-return packet


def run(payload, stamps, chunk=151, **options):
    """Frames and decoder of ``payload`` pushed in chunks; only lidarpkt's errors and warnings may come out."""
    decoder = RobosenseDecoder(**options)
    frames = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for a in range(0, len(payload), chunk):
            frames += decoder.push(PacketBatch.from_payloads(payload[a:a + chunk], stamps[a:a + chunk], first_index=a))
        frames += decoder.finish()
    return frames, decoder


def returns(frames) -> int:
    return sum(int(np.count_nonzero(f.range_mm)) for f in frames)


@pytest.fixture(scope="module")
def bag():
    return all_packets()


@pytest.fixture(scope="module")
def baseline(bag):
    return run(*bag)


@pytest.mark.parametrize("model", MODELS, ids=[m.name for m in MODELS])
def test_random_bytes_under_a_valid_header_raise_nothing_but_lidarpkt_errors(model):
    rng = np.random.default_rng(7)
    payload = rng.integers(0, 256, (400, P.PACKET_SIZE), dtype=np.uint8)
    view = payload.view(model.layout)[:, 0]
    ident = P.MSOP_ID_V1 if model.family == "v1" else P.MSOP_ID_V2
    view["header"]["header_id"] = np.frombuffer(ident, np.uint8)
    view["blocks"]["flag"] = P.RUBY_BLOCK_FLAG if model.family == "ruby" else P.BLOCK_FLAG
    half = rng.random(400) < 0.5
    view["blocks"]["azimuth"][half] %= 36000  # half of them with possible azimuths too
    difop = rng.integers(0, 256, (20, P.PACKET_SIZE), dtype=np.uint8)
    difop[:, :8] = np.frombuffer(P.DIFOP_ID, np.uint8)
    rows = np.concatenate([difop[:10], payload, difop[10:]])
    for hosts in (np.zeros(len(rows), np.int64), np.sort(rng.integers(0, 1 << 62, len(rows)))):
        try:
            frames, decoder = run(rows, hosts, chunk=37)
        except LidarpktError:
            continue
        st = decoder.stats
        assert st.decoded_packets + st.malformed_fields + st.corrupted_packets + st.duplicate_packets + \
            st.late_packets == st.packets == 400
        for f in frames:  # what is decoded is a frame lidarpkt can use
            f.points() if f.sensor.geometry is not None else f.has_return()
    counter = PacketCounter(model)
    counter.update(rows)
    assert counter.count.packets == 400


def test_flipped_bytes_are_counted_and_losses_stay_physical(bag, baseline):
    payload, stamps = bag
    rng = np.random.default_rng(11)
    span_packets = (stamps[-1] - stamps[0]) / PERIOD_NS
    for _trial in range(6):
        bad = payload.copy()
        rows = rng.choice(len(bad), 40, replace=False)
        cols = rng.integers(0, P.PACKET_SIZE, 40)
        bad[rows, cols] ^= rng.integers(1, 256, 40).astype(np.uint8)
        frames, decoder = run(bad, stamps)
        st = decoder.stats
        assert st.packets == 750 and st.difop_packets == 1
        assert st.decoded_packets + st.malformed_fields + st.corrupted_packets + st.duplicate_packets + \
            st.late_packets == 750
        assert st.decoded_packets >= 750 - 40
        assert st.lost_packets + st.decoded_packets <= span_packets + 2
        assert returns(frames) >= returns(baseline[0]) - 40 * 32


def test_cut_packets_and_foreign_sizes_are_skipped_and_counted(bag):
    payload, stamps = bag
    decoder = RobosenseDecoder()
    with pytest.warns(Warning, match="no RoboSense model sends"):
        assert decoder.push(PacketBatch.from_payloads(payload[:50, :1000], stamps[:50])) == []
    assert decoder.stats.malformed_size == 50
    frames = []
    for batch in batches():
        frames += decoder.push(batch)
    frames += decoder.finish()
    assert decoder.stats.decoded_packets == 750 and len(frames) == 6


def test_a_difop_with_nonsense_angles_is_refused(bag, baseline):
    payload, stamps = bag
    bad = payload.copy()
    k = int(np.flatnonzero(bad[:, 0] == 0xA5)[0])
    bad[k, 468:660] = 0xFF  # sign bytes 0xFF, magnitudes 655.35°
    frames, decoder = run(bad, stamps, difop_wait_s=1.0)
    assert decoder.stats.difop_malformed == 1 and decoder.device is None
    assert returns(frames) == returns(baseline[0])  # every return still decoded
    assert all(f.sensor.geometry is None for f in frames)
    with pytest.raises(CalibrationError, match="calibration"):
        frames[1].xyz()
    assert frames[1].return_labels == ("unknown",)
    # with the sensor's CSV the frames have points again; its 16 angles do not fit 32 lasers: one error
    with pytest.raises(CalibrationError, match="16 lasers for a sensor of 32"):
        run(bad, stamps, calibration=str(external(CSV)))
    frames16, _ = run(bad, stamps, model="RS-Helios-16P", calibration=str(external(CSV)))
    assert frames16[1].sensor.metadata["calibration_source"].endswith("RobosenseHelios16P.csv")
    assert frames16[1].xyz().shape == (1, 16, 3600, 3)


def test_lost_packets_are_counted_from_the_packet_counter(bag, baseline):
    payload, stamps = bag
    keep = np.ones(len(payload), bool)
    keep[100:110] = False  # 10 MSOP packets
    keep[400] = False
    frames, decoder = run(payload[keep], stamps[keep])
    assert decoder.stats.lost_packets == 11
    assert sum(f.counters.lost_packets for f in frames) == 11
    counter = PacketCounter()
    counter.update(payload[keep], stamps[keep])
    assert counter.count.lost == 11 and counter.count.packets == 739


def test_repeated_and_reordered_packets(bag, baseline):
    payload, stamps = bag
    order = np.arange(len(payload))
    order[200:204] = [202, 200, 203, 201]
    again = np.r_[order[:300], order[290:300], order[300:]]
    frames, decoder = run(payload[again], stamps[again], chunk=1000)
    # out of order: the steps back in arrival order (200 after 202, 201 after 203, 290 after 299)
    assert decoder.stats.duplicate_packets == 10 and decoder.stats.out_of_order_packets == 3
    assert decoder.stats.lost_packets == 0
    assert [f.range_mm.tobytes() for f in frames] == [f.range_mm.tobytes() for f in baseline[0]]


def test_a_corrupted_time_is_skipped_not_a_loss_and_drops_nothing_good(bag, baseline):
    payload, stamps = bag
    bad = payload.copy()
    bad[300, 22] ^= 0x40  # the packet's seconds jump ~2 years
    frames, decoder = run(bad, stamps)
    assert decoder.stats.corrupted_packets == 1 and decoder.stats.lost_packets == 1  # its place, lost
    assert decoder.stats.late_packets == 0 and decoder.stats.decoded_packets == 749
    assert returns(frames) >= returns(baseline[0]) - 32 * 12


def test_a_restart_is_counted_not_lost(bag):
    payload, stamps = bag
    again = payload.copy()
    msop = again[:, 0] == 0x55
    seconds = again[msop, 20:26].astype(np.int64) @ (256 ** np.arange(5, -1, -1))
    seconds -= 3600  # the sensor restarted: its clock began again, an hour back
    again[msop, 20:26] = (seconds[:, None] >> (8 * np.arange(5, -1, -1))) & 0xFF
    both = np.concatenate([payload, again])
    hosts = np.concatenate([stamps, stamps + 2_000_000_000])
    frames, decoder = run(both, hosts)
    st = decoder.stats
    assert (st.restarts, st.lost_packets, st.late_packets, st.corrupted_packets) == (1, 0, 0, 0)
    assert st.decoded_packets == 1500 and len(frames) == 12


def test_no_difop_waits_then_decodes_without_calibration_and_a_late_difop_gives_one(bag):
    payload, stamps = bag
    frames, decoder = run(payload, stamps, difop_wait_s=0.05)
    sources = [f.sensor.metadata["calibration_source"] for f in frames]
    assert sources[0] is None and sources[-1] == "DIFOP"
    assert frames[0].sensor.geometry is None and frames[-1].sensor.geometry is not None
    assert decoder.stats.decoded_packets == 750


def test_a_difop_before_any_msop_is_read_with_the_model_the_msop_tells(bag):
    payload, stamps = bag
    k = int(np.flatnonzero(payload[:, 0] == 0xA5)[0])
    order = np.r_[k, np.delete(np.arange(len(payload)), k)]
    frames, decoder = run(payload[order], stamps[order])
    assert decoder.stats.difop_packets == 1 and decoder.stats.difop_malformed == 0
    assert frames[0].sensor.metadata["calibration_source"] == "DIFOP"
    helios = [m for m in MODELS if m.name == "RS-Helios"][0]
    auxiliary = RobosenseDecoder()
    auxiliary.push_auxiliary(PacketBatch.from_payloads(
        encode_difop(helios, return_mode=0x00, elevation_deg=np.linspace(15, -55, 32))[None], [1]))
    assert auxiliary.stats.difop_packets == 1 and auxiliary.device is None  # read once the model is known
