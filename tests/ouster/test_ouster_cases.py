"""Shared cases of the Ouster tests: the real captures, their metadata and digests (no tests here)."""

from __future__ import annotations

import json

import numpy as np

from conftest import external
from lidarpkt.vendors.ouster import OusterDecoder, classify, load_metadata
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.pcap_reader import read_batches

# (capture, metadata files, published digest or None)
CAPTURES = [
    ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", ["ouster-sdk/OS-1-64_sensor_config_reduced.json"], None),
    ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", ["ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"], "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10_digest.json"),
    ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10-single-packet.pcap", ["ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"], None),
    ("ouster-sdk/OS-1-32-G_v2.1.1_1024x10.pcap", ["ouster-sdk/OS-1-32-G_v2.1.1_1024x10.json"], "ouster-sdk/OS-1-32-G_v2.1.1_1024x10_digest.json"),
    ("ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.pcap", ["ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.json"], "ouster-sdk/OS-2-32-U0_v2.0.0_1024x10_digest.json"),
    ("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", ["ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json"], "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10_digest.json"),
    ("ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap", ["ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json"], "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10_digest.json"),
    ("ouster-sdk/crc_test.pcap", ["ouster-sdk/crc_test.json"], None),
    ("ouster-sdk/duplicate_id.pcap", ["ouster-sdk/duplicate_id.json"], None),
    ("ouster-sdk/empty_pcap.pcap", ["ouster-sdk/empty_pcap.json"], None),
    ("ouster-sdk/same_ports_legacy.pcap", ["ouster-sdk/same_ports_legacy.1.json", "ouster-sdk/same_ports_legacy.2.json"], None),
    ("ouster-sdk/same_ports_nonlegacy.pcap", ["ouster-sdk/same_ports_nonlegacy.1.json", "ouster-sdk/same_ports_nonlegacy.2.json"], None),
    ("rust-lidar-utils/ouster_example.pcap", ["rust-lidar-utils/ouster_example.json"], None),
    # firmware 3.x: RNG19 single with an ACCEL32_GYRO32_NMEA IMU, FARTHEST_TO_NEAREST, shot limiting in the header
    ("ouster-sdk/shot_limiting_test.pcap", ["ouster-sdk/shot_limiting_test.json"], None),
    ("ouster-sdk/OS-1-128_767798045_1024x10_20230712_120049.pcap", ["ouster-sdk/OS-1-128_767798045_1024x10_20230712_120049.json"], None),
    ("ouster-sdk/same_ports.pcap", ["ouster-sdk/same_ports.1.json", "ouster-sdk/same_ports.2.json", "ouster-sdk/same_ports.2.non_colliding_imu.json"], None),
    ("ouster-sdk/OS-1-128_v2.3.0_1024x10_lb_n3.pcap", ["ouster-sdk/OS-1-128_v2.3.0_1024x10.json"], None),
    ("ouster-sdk/windowed_frame1.pcap", ["ouster-sdk/windowed_frame1_0.json"], None),
    ("ouster-sdk/windowed_frame2.pcap", ["ouster-sdk/windowed_frame2_0.json"], None),
]
DIGESTED = [c for c in CAPTURES if c[2]]
IDS = [c[0].split("/")[-1] for c in CAPTURES]


def metadata_of(jsons: list[str]):
    return [load_metadata(external(j)) for j in jsons]


def lidar_streams(pcap: str, jsons: list[str]) -> list[tuple[object, PacketBatch]]:
    """[(metadata, all lidar packets of that sensor as one batch)] via classify, capture order."""
    mds = metadata_of(jsons)
    per: dict[tuple, list[PacketBatch]] = {}
    owner: dict[tuple, object] = {}
    for batch in read_batches(external(pcap)):
        match = classify(batch, mds)
        if match and match[0] == "lidar":
            key = (batch.src, id(match[1]))
            per.setdefault(key, []).append(batch)
            owner[key] = match[1]
    return [(owner[k], PacketBatch.concatenate(v)) for k, v in per.items()]


def decode_frames(pcap: str, jsons: list[str], **options):
    """All frames of a capture, one OusterDecoder per (source address, metadata); and the decoders."""
    mds = metadata_of(jsons)
    decoders: dict[tuple, OusterDecoder] = {}
    frames = []
    for batch in read_batches(external(pcap)):
        match = classify(batch, mds)
        if not match:
            continue
        kind, md = match
        key = (batch.src.address if batch.src else None, id(md))
        dec = decoders.setdefault(key, OusterDecoder(md, source=str(batch.src), **options))
        if kind == "lidar":
            frames += dec.push(batch)
        else:
            dec.push_imu(batch)
    for dec in decoders.values():
        frames += dec.finish()
    return frames, decoders


def load_digest(rel: str) -> dict:
    return json.loads(external(rel).read_text())


def all_packets_of_size(pcap: str, size: int) -> np.ndarray:
    """Every payload of ``size`` bytes in the capture, capture order (any source)."""
    rows = [b for b in read_batches(external(pcap)) if b.payload_size == size]
    if not rows:
        return np.zeros((0, size), np.uint8)
    order = np.argsort(np.concatenate([b.index for b in rows]), kind="stable")
    return np.concatenate([b.payload for b in rows])[order]
