"""Which Ouster sensor (if any) sent a stream: with metadata (exact), or a guess from size and header.

Packet size alone does not identify a profile (8448 B is both 32-channel
RNG19_RFL8_SIG16_NIR16_DUAL and 128-channel RNG15_RFL8_NIR8; 16640 B both 64-channel
RNG19…DUAL and 128-channel FUSA_RNG15_RFL8_NIR8_DUAL), so with metadata the size is checked
first, then the init_id and serial in the packet header (non-legacy profiles).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from lidarpkt.core.median import median
from lidarpkt.core.packet import PacketBatch
from .crc import footer_crc_ok
from .decode import decode_packets
from .imu import decode_imu, imu_samples
from .metadata import OusterMetadata
from .profiles import GUESS_ROWS, HEADER_BYTES, HEADER_TYPES, PROFILES, Profile, guessable_packet_sizes
from .auxiliary import IMU_PACKET_SIZE
from .bitfield import read_bits
from .zone import decode_zone_packets



#: ``packet_type`` of the non-legacy packet header: lidar, IMU (ACCEL32_GYRO32_NMEA), zone monitoring.
PACKET_TYPE_LIDAR, PACKET_TYPE_IMU, PACKET_TYPE_ZONE = 1, 2, 3


def _ids_match(batch: PacketBatch, md: OusterMetadata, header_fields=None) -> np.ndarray:
    """``bool[N]``: the header's serial (and init_id, when the metadata has one) are the metadata's."""
    header_fields = header_fields or md.profile.header_fields or HEADER_TYPES["STANDARD"]
    header = batch.payload[:, :HEADER_BYTES]
    ok = np.ones(len(batch), bool)
    fields = {f.name: f for f in header_fields}
    if md.serial_int is not None:
        ok &= read_bits(header, fields["prod_sn"]) == np.uint64(md.serial_int)
    if md.init_id:
        ok &= read_bits(header, fields["init_id"]) == md.init_id
    return ok


def classify(batch: PacketBatch, metadata: Sequence[OusterMetadata]) -> tuple[str, OusterMetadata] | None:
    """``("lidar", md)`` / ``("imu", md)`` / ``("zone", md)`` when the batch is a stream of the sensor of
    ``md``, else ``None``.

    Lidar: the payload size must be the metadata's packet size; for non-legacy profiles the
    init_id and serial of the packet header must match too (for most of the batch). LEGACY
    packets carry no identity: the first metadata of the right size wins. LEGACY IMU (48 B): the
    metadata whose IMU port is the destination port, else the first one when the accelerations
    are plausible (|a| between 0.5 and 2 g). ACCEL32_GYRO32_NMEA IMU and zone-monitoring packets
    (680 B) carry the packet header: its packet type (2, 3), init_id and serial must match.
    """
    if len(batch) == 0 or not metadata:
        return None
    size = batch.payload_size
    for kind, md in _headed_matches(batch, metadata):
        return kind, md
    if size == IMU_PACKET_SIZE and any(md.imu_profile == "LEGACY" for md in metadata):
        metadata = [md for md in metadata if md.imu_profile == "LEGACY"]
        port = batch.dst.port if batch.dst is not None else None
        for md in metadata:
            if md.imu_port == port:
                return "imu", md
        return ("imu", metadata[0]) if _imu_plausible(batch.payload) else None
    for md in metadata:
        if md.packet_size != size or not md.lidar_enabled:
            continue
        if md.profile.legacy:
            if _legacy_plausible(batch.payload, md.profile, md.pixels_per_column):
                return "lidar", md
            continue
        if _ids_match(batch, md).mean() >= 0.5:
            return "lidar", md
    return None


def _headed_matches(batch: PacketBatch, metadata: Sequence[OusterMetadata]):
    """(kind, md) of ACCEL32_GYRO32_NMEA IMU or zone-monitoring packets of the sizes, packet types and
    identities of ``metadata`` (most of the batch)."""
    size = batch.payload_size
    if size < HEADER_BYTES:
        return
    for md in metadata:
        header_type = md.header_type or "STANDARD"
        if size == md.imu_packet_size and md.imu_profile != "LEGACY":
            kind, ptype = "imu", PACKET_TYPE_IMU
        elif size == md.zone_packet_size and not md.profile.legacy:
            kind, ptype = "zone", PACKET_TYPE_ZONE
        else:
            continue
        fields = HEADER_TYPES[header_type]
        ptype_field = next(f for f in fields if f.name == "packet_type")
        ok = _ids_match(batch, md, fields) & (read_bits(batch.payload[:, :HEADER_BYTES], ptype_field) == ptype)
        if ok.mean() >= 0.5:
            yield kind, md


def _imu_plausible(payload: np.ndarray) -> bool:
    """48-byte packets that read as an IMU carried by a sensor at rest or on a vehicle (|a| 0.5–2 g)."""
    samples = decode_imu(payload)
    a = np.stack([samples[k].astype(np.float64) for k in ("accel_x_g", "accel_y_g", "accel_z_g")])
    with np.errstate(all="ignore"):  # junk bytes read as NaN/huge floats: simply not plausible
        accel = np.sqrt((a**2).sum(axis=0))
    return bool(0.5 < median(accel) < 2.0)


def _legacy_plausible(payload: np.ndarray, profile: Profile, h: int) -> bool:
    """Column measurement ids step by one inside the first packet (LEGACY has no other signature)."""
    first = payload[:1]
    try:
        cols = first.view(profile.packet_dtype(h, 16))[:, 0]["columns"]
    except ValueError:
        return False
    mids = cols["measurement_id"][0].astype(np.int64)
    return bool(np.all(np.diff(mids) == 1))


def _guesses(payload: np.ndarray) -> list[tuple[Profile, int]]:
    """(profile, pixels_per_column) layouts consistent with the packet size and column headers,
    most plausible first.

    Ranking (a guess, for ``info`` without metadata): a FUSA layout is unlikely when the packet
    also reads as a standard header (byte 1 = 0, the high byte of packet type 0x0001, where FUSA
    has the init_id); a RNG19…DUAL layout is unlikely when, where both returns exist, the first
    return is not the stronger one (the manual orders them strongest first).
    """
    size = payload.shape[1]
    ranked = []
    for order, profile in enumerate(PROFILES.values()):
        for h in GUESS_ROWS:
            if profile.packet_size(h, 16) != size:
                continue
            cols = payload[:1].view(profile.packet_dtype(h, 16))[:, 0]["columns"]
            mids = cols["measurement_id"][0].astype(np.int64)
            if not np.all(np.diff(mids) == 1):
                continue
            unlikely = False
            if not profile.legacy:
                ptype = read_bits(payload[:1, :32], {f.name: f for f in profile.header_fields}["packet_type"])[0]
                if int(ptype) != 1:
                    continue
                if profile.name.startswith("FUSA") and payload[0, 1] == 0:
                    unlikely = True
                if "SIGNAL2" in profile.field_names:
                    f = decode_packets(payload[:8], _Layout(profile, h), verify_crc=False, fields=("RANGE", "RANGE2", "SIGNAL", "SIGNAL2"))
                    both = (f.pixels["RANGE"] > 0) & (f.pixels["RANGE2"] > 0)
                    if both.sum() >= 100 and (f.pixels["SIGNAL"][both] >= f.pixels["SIGNAL2"][both]).mean() < 0.9:
                        unlikely = True
            ranked.append((unlikely, order, profile, h))
    ranked.sort(key=lambda t: (t[0], t[1]))
    return [(p, h) for _, _, p, h in ranked]


def guess(batch: PacketBatch) -> str | None:
    """What a stream no metadata fits looks like, as :func:`describe_stream` guesses it: ``"lidar"`` (the size
    and column headers of some profile), ``"imu"`` (48-byte packets that read as an IMU's) or ``None``."""
    size = batch.payload_size
    if len(batch) == 0:
        return None
    if size == IMU_PACKET_SIZE:
        return "imu" if _imu_plausible(batch.payload) else None
    if size not in guessable_packet_sizes():
        return None
    return "lidar" if _guesses(batch.payload) else None


def describe_stream(batch: PacketBatch, metadata: Sequence[OusterMetadata] = ()) -> dict | None:
    """A summary of an Ouster stream for ``lidarpkt info``, or ``None`` if it is not one.

    Lidar: ``{"kind": "Ouster lidar", "profile", "profile_source": "metadata" | "guess",
    "pixels_per_column", "packets", "frame_id": [first, last], "columns": measurement ids seen,
    "crc": "valid" | "invalid" | "absent", ...}``. Without metadata the profile is a guess from
    the size and header (``"candidates"`` lists every layout that fits, e.g. two for 8448 B).
    Non-legacy lidar streams also count the packets whose header reports shot limiting or a coming
    thermal shutdown (``"shot_limiting_packets"``, ``"thermal_shutdown_packets"``).
    IMU: ``{"kind": "Ouster IMU", "packets", "imu_profile", "samples", ...}``.
    Zone monitoring: ``{"kind": "Ouster zone monitoring", "packets", "zones_live", "zones_triggered"}``.
    """
    if len(batch) == 0:
        return None
    match = classify(batch, metadata) if metadata else None
    if match is not None and match[0] == "zone":
        z = decode_zone_packets(batch.payload, match[1].header_type or "STANDARD")
        return {"kind": "Ouster zone monitoring", "packets": len(batch), "profile_source": "metadata",
                "timestamp_ns": [int(z.timestamp_ns[0]), int(z.timestamp_ns[-1])],
                "zones_live": int(np.count_nonzero(z.zones["live"][-1])),
                "zones_triggered": int(np.count_nonzero(z.zones["trigger_status"][-1] & z.zones["live"][-1]))}
    if match is not None and match[0] == "imu" and match[1].imu_profile != "LEGACY":
        imu_md = match[1]
        imu = imu_samples(batch.payload, imu_md)
        out = {"kind": "Ouster IMU", "packets": len(batch), "profile_source": "metadata", "imu_profile": imu_md.imu_profile,
               "samples": len(imu)}
        if len(imu):
            out["timestamp_ns"] = [int(imu.timestamp_ns[0]), int(imu.timestamp_ns[-1])]
        return out
    if match is not None and match[0] == "imu" or (match is None and batch.payload_size == IMU_PACKET_SIZE):
        if match is None and not _imu_plausible(batch.payload):
            return None  # 48 bytes that do not read as an IMU
        samples = decode_imu(batch.payload)
        out = {"kind": "Ouster IMU", "packets": len(batch), "profile_source": "metadata" if match else "guess",
               "imu_profile": "LEGACY", "samples": len(batch)}
        out["sys_timestamp_ns"] = [int(samples["sys_timestamp_ns"][0]), int(samples["sys_timestamp_ns"][-1])]
        return out
    md: OusterMetadata | None = None
    if match is not None:
        md = match[1]
        profile, h, source, candidates = md.profile, md.pixels_per_column, "metadata", [md.profile.name]
    else:
        guesses = _guesses(batch.payload)
        if not guesses:
            return None
        profile, h = guesses[0]
        source, candidates = "guess", [f"{p.name} ({rows} px)" for p, rows in guesses]
    fields = decode_packets(batch.payload, md if md is not None else _Layout(profile, h), verify_crc=False, fields=(),
                            header_fields=("frame_id", "init_id", "prod_sn", "shot_limiting", "thermal_shutdown"))
    frame_ids = fields.frame_id
    mids = fields.measurement_id
    if profile.legacy:
        crc = "absent"
    else:
        ok = footer_crc_ok(batch.payload)
        if ok.all():
            crc = "valid"
        elif md is not None and md.footer_kind == "crc":
            crc = "invalid"
        else:
            crc = "absent"
    out = {
        "kind": "Ouster lidar",
        "profile": profile.name,
        "profile_source": source,
        "candidates": candidates,
        "pixels_per_column": h,
        "packet_size": batch.payload_size,
        "packets": len(batch),
        "frame_id": [int(frame_ids[0]), int(frame_ids[-1])],
        "frames": int(np.unique(frame_ids).size),
        "columns": int(np.unique(mids).size),
        "measurement_id": [int(mids.min()), int(mids.max())],
        "crc": crc,
    }
    if not profile.legacy:
        out["init_id"] = int(fields.header["init_id"][0])
        out["serial"] = str(int(fields.header["prod_sn"][0]))
        out["header_type"] = profile.header_type
        out["shot_limiting_packets"] = int(np.count_nonzero(fields.header["shot_limiting"]))
        out["thermal_shutdown_packets"] = int(np.count_nonzero(fields.header["thermal_shutdown"]))
    if md is not None:
        out["crc_failures"] = int((~footer_crc_ok(batch.payload)).sum()) if md.footer_kind == "crc" else 0
    return out


class _Layout:
    """The bits of metadata decode_packets needs, for a guessed layout."""

    def __init__(self, profile: Profile, h: int) -> None:
        self.profile = profile
        self.pixels_per_column = h
        self.columns_per_packet = 16
        self.footer_kind = "unknown"
