"""Differential tests: lidarpkt's VLP-16 points against velodyne_decoder 3.1.0, firing by firing.

Both decoders get the same packets. velodyne_decoder decodes them as one scan
(``ScanDecoder.decode``); lidarpkt decodes them to frames and flattens them with
``frame_points``. Points are matched by firing time (velodyne_decoder's float32 time,
relative to the last packet, lands within 1 µs of our exact firing time; firings are
≥ 2.304 µs apart) and return label; then ring, intensity and XYZ (≤ 1 mm) must agree and
no point may be missing on either side.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne import VelodyneDecoder, encode_data_packets, frame_points
from lidarpkt.vendors.velodyne.timing import SEQUENCE_NS

pytestmark = pytest.mark.crosscheck


def _reference_points(vd, batch: PacketBatch, *, product_id_override: int | None = None, calibration=None):
    cfg = vd.Config(model=vd.Model.VLP16)
    if calibration is not None:  # a ROS YAML: the one calibration format velodyne_decoder reads
        cfg.calibration = vd.Calibration.read(str(calibration))
    cfg.min_range = 0.0
    cfg.max_range = 1e4
    packets = vd.PacketVector()
    for t, row in zip(batch.timestamp_ns.tolist(), batch.payload):
        data = row.copy()
        if product_id_override is not None:
            data[1205] = product_id_override  # velodyne_decoder insists on 0x22 for a VLP-16
        packets.append(vd.VelodynePacket(t / 1e9, data.tobytes()))
    _, points = vd.ScanDecoder(cfg).decode(packets, True)
    return points


def _our_points(batch: PacketBatch, **options):
    dec = VelodyneDecoder(**options)
    frames = dec.push(batch) + dec.finish()
    per_packet = 12 if frames[-1].shape[0] == 2 else 24
    last = frames[-1]
    last_packet_ns = int(last.column_timestamp_ns[last.column_valid].max()) - (per_packet - 1) * SEQUENCE_NS
    pts = np.concatenate([frame_points(f) for f in frames])
    return pts, last_packet_ns, frames


def assert_same_points(batch: PacketBatch, *, product_id_override: int | None = None, calibration=None,
                       our_calibration=None) -> int:
    """Points of lidarpkt and velodyne_decoder agree; ``calibration`` (ROS YAML) is given to both, or
    ``our_calibration`` (e.g. the same values as VeloView XML) to lidarpkt instead."""
    vd = pytest.importorskip("velodyne_decoder")
    ref = _reference_points(vd, batch, product_id_override=product_id_override, calibration=calibration)
    ours, t_ref, _ = _our_points(batch, calibration=our_calibration or calibration)
    t_ours = ours["time_ns"] - t_ref
    firings = np.unique(t_ours)
    t_theirs = ref["time"].astype(np.float64) * 1e9
    i = np.clip(np.searchsorted(firings, t_theirs), 1, len(firings) - 1)
    i = np.where(np.abs(firings[i - 1] - t_theirs) < np.abs(firings[i] - t_theirs), i - 1, i)
    assert np.abs(firings[i] - t_theirs).max() < 1000, "a reference point matches no firing of ours"
    key_ours = np.stack([np.searchsorted(firings, t_ours), ours["return_type"]], 1)
    key_ref = np.stack([i, ref["return_type"].astype(np.int64)], 1)
    assert len(ours) == len(ref)
    oa, ob = np.lexsort(key_ours.T[::-1]), np.lexsort(key_ref.T[::-1])
    np.testing.assert_array_equal(key_ours[oa], key_ref[ob])
    np.testing.assert_array_equal(ours["ring"][oa], ref["ring"][ob])
    np.testing.assert_array_equal(ours["intensity"][oa], ref["intensity"][ob].astype(np.uint8))
    for axis in "xyz":
        assert np.abs(ours[axis][oa] - ref[axis][ob]).max() < 1e-3, axis
    return len(ours)


# ------------------------------------------------------------------ real captures
def test_strongest_capture_matches(ext):
    from lidarpkt.containers.pcap_reader import PcapReader

    batches = [b for b in PcapReader(ext("rust-lidar-utils/velodyne_example.pcap")).batches() if b.payload_size == 1206]
    assert assert_same_points(PacketBatch.concatenate(batches)) > 30000


def test_early_unit_0x21_capture_matches(ext):
    from lidarpkt.containers.pcap_reader import PcapReader

    batches = [b for b in PcapReader(ext("rust-lidar-utils/velodyne_vlp16.pcap")).batches() if b.payload_size == 1206]
    assert assert_same_points(PacketBatch.concatenate(batches), product_id_override=0x22) > 15000


def test_veloview_20hz_capture_matches(ext):
    """1902 packets at 20 Hz, including one whose block azimuth reads 36000 (= 0°)."""
    from lidarpkt.containers.pcap_reader import PcapReader
    from lidarpkt.vendors.velodyne import decode_packets

    path = ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    batch = PacketBatch.concatenate([b for b in PcapReader(path).batches() if b.payload_size == 1206])
    assert np.any(decode_packets(batch.payload).azimuth_cdeg == 36000)
    assert assert_same_points(batch, product_id_override=0x22) > 500000


def test_einride_recording_matches(ext):
    payload = np.fromfile(ext("einride-vlp16-go/recording.bin"), np.uint8).reshape(-1, 1206)
    # raw payloads have no capture time: give a plausible host clock at the nominal packet rate
    host = 1_525_349_000_000_000_000 + np.arange(len(payload), dtype=np.int64) * 1_327_104
    assert assert_same_points(PacketBatch.from_payloads(payload, host)) > 200000


def test_dual_bag_matches(ext):
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages

    batch = PacketBatch.concatenate(list(BagReader(ext("nebula/vlp16/1673400471837873222"), messages=bag_messages()).batches()))
    assert assert_same_points(batch) > 55000


# ------------------------------------------------------------------ generated packets
def synthetic_packets(mode: str, n: int = 200, seed: int = 1, rpm: float = 600.0) -> PacketBatch:
    """Packets of a sensor turning at ``rpm``: random ranges (a fifth empty), dual pairs that are
    equal, differ in range, differ only in reflectivity, or have one empty slot."""
    rng = np.random.default_rng(seed)
    dual = mode == "dual"
    period_us = 1327.104 / (2 if dual else 1)
    t_us = 1_000_000 + np.arange(n) * period_us
    cdeg_per_us = rpm / 60 * 36000 / 1e6
    block_t = np.arange(12) // (2 if dual else 1) * 2 * 55.296  # time of each block's first firing
    az = np.rint((t_us[:, None] + block_t[None, :]) * cdeg_per_us + 1234).astype(np.int64) % 36000
    dist = rng.integers(150, 60000, size=(n, 12, 32))
    dist[rng.random(dist.shape) < 0.2] = 0
    refl = rng.integers(0, 256, size=(n, 12, 32))
    if dual:
        last, strong = dist[:, 0::2], dist[:, 1::2]
        r_last, r_strong = refl[:, 0::2], refl[:, 1::2]
        kind = rng.integers(0, 5, size=last.shape)
        strong[kind == 0] = last[kind == 0]  # one return: both blocks hold it
        r_strong[kind == 0] = r_last[kind == 0]
        strong[kind == 1] = last[kind == 1]  # same range, other reflectivity
        last[kind == 2] = 0  # only a strongest
        dist[:, 0::2], dist[:, 1::2], refl[:, 0::2], refl[:, 1::2] = last, strong, r_last, r_strong
    payload = encode_data_packets(az, dist, refl, np.rint(t_us).astype(np.int64), mode)
    host = 1_700_000_000_000_000_000 + np.rint(t_us * 1000).astype(np.int64)
    return PacketBatch.from_payloads(payload, host)


@pytest.mark.parametrize("mode", ["strongest", "last", "dual"])
def test_generated_packets_match(mode):
    assert assert_same_points(synthetic_packets(mode)) > 1000


@pytest.mark.parametrize("rpm", [300.0, 1200.0])
def test_generated_other_rotation_rates_match(rpm):
    assert assert_same_points(synthetic_packets("strongest", n=120, seed=3, rpm=rpm)) > 1000


def test_absolute_times_match_velodyne_decoder(ext):
    """velodyne_decoder's device stamp of each scan (packet µs past the hour + the hour nearest the
    capture time) is exactly the timestamp of one of our columns. This capture's sensor clock is
    29.8 min off the host's, close to the ±30 min limit of the nearest-hour rule."""
    vd = pytest.importorskip("velodyne_decoder")
    import lidarpkt

    path = ext("rust-lidar-utils/velodyne_example.pcap")
    stamps = [s.device for s, _ in vd.read_pcap(str(path), vd.Config(model=vd.Model.VLP16))]
    assert len(stamps) == 2
    ours = np.concatenate([f.column_timestamp_ns for f in lidarpkt.open(path)])
    for s in stamps:
        assert np.min(np.abs(ours - round(s * 1e6) * 1000)) == 0
