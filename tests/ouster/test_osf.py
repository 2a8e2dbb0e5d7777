"""OSF files (ouster-sdk's recordings of decoded frames): every frame equal to ouster-sdk 1.0.1's OSF reader, the
damaged ones one clear error, the verbs taking OSF as input, and no other error than lidarpkt's on mutated copies."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import time
import warnings
import zlib

import numpy as np
import pytest

import lidarpkt
from conftest import REPO_ROOT, external
from lidarpkt.errors import CaptureFormatError, LidarpktError, UnsupportedContainerError

GOOD = ["osf_fw_3.2_10scans.osf", "OS-1-128_v2.3.0_1024x10_lb_n3.osf", "OS-0-128_v3.0.1_1024x10_20241017_141645.osf",
        "single_scan_016.osf", "single_frame_zm.osf"]
DAMAGED = ["bad_crc32.osf", "bad_encoding.osf", "bad_16_bit_fields.osf"]

# ours (attribute, return slot) for each SDK channel field; every other field is frame.extra[name.lower()]
FIELD_MAP = {"RANGE": ("range_mm", 0), "RANGE2": ("range_mm", 1), "SIGNAL": ("signal", 0), "SIGNAL2": ("signal", 1),
             "REFLECTIVITY": ("reflectivity", 0), "REFLECTIVITY2": ("reflectivity", 1), "FLAGS": ("flags", 0),
             "FLAGS2": ("flags", 1), "NEAR_IR": ("near_ir", None)}


def sdk_osf(path):
    osf = pytest.importorskip("ouster.sdk.osf")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        src = osf.OsfFrameSetSource(str(path))
        frames = [f for fs in src for f in fs if f is not None]
        return frames, list(src.sensor_info)


@pytest.mark.crosscheck
@pytest.mark.parametrize("name", GOOD)
def test_osf_frames_equal_ouster_sdk(name):
    path = external("ouster-sdk/" + name)
    theirs, infos = sdk_osf(path)
    with lidarpkt.open(path) as reader:
        ours = list(reader)
    assert len(ours) == len(theirs) > 0
    for mine, sdk in zip(ours, theirs):
        assert mine.frame_id == sdk.frame_id
        for field in sdk.fields:
            want = sdk.field(field)
            if field in FIELD_MAP:
                attr, slot = FIELD_MAP[field]
                got = getattr(mine, attr)
                got = got if slot is None else got[slot]
            else:
                got = mine.extra[field.lower()]
            assert got.shape == want.shape, field
            if want.dtype.names:  # ZONE_STATES: records, compared byte for byte
                assert got.dtype.itemsize == want.dtype.itemsize and got.tobytes() == want.tobytes(), field
            else:
                assert np.array_equal(got, want), f"frame {mine.frame_id} field {field}"
        header = {"packet_timestamp_ns", "alert_flags", "thermal_shutdown", "shot_limiting", "countdown_thermal_shutdown",
                  "countdown_shot_limiting", "pose"}
        ours_only = {k for k in mine.extra if k.upper() not in sdk.fields} - header
        assert not ours_only, f"fields ouster-sdk does not give: {ours_only}"
        np.testing.assert_array_equal(mine.column_timestamp_ns, sdk.timestamp.astype(np.int64))
        np.testing.assert_array_equal(mine.measurement_id, sdk.measurement_id)
        np.testing.assert_array_equal(mine.status, sdk.status)
        # per packet (and per frame) in the file and ouster-sdk, per column in a frame: each column its packet's
        per_packet = sdk.w // len(sdk.packet_timestamp)
        np.testing.assert_array_equal(mine.extra["packet_timestamp_ns"], np.repeat(sdk.packet_timestamp, per_packet))
        np.testing.assert_array_equal(mine.extra["alert_flags"], np.repeat(sdk.alert_flags, per_packet))
        for key, want in (("thermal_shutdown", int(sdk.thermal_shutdown())), ("shot_limiting", int(sdk.shot_limiting())),
                          ("countdown_thermal_shutdown", sdk.shutdown_countdown),
                          ("countdown_shot_limiting", sdk.shot_limiting_countdown)):
            assert mine.extra[key].shape == (sdk.w,) and (mine.extra[key] == want).all(), key
        assert mine.partial == (not sdk.complete())
        # the metadata the file holds
        info = infos[0]
        assert (mine.sensor.serial, mine.sensor.model, mine.sensor.firmware) == (str(info.sn), info.prod_line, info.fw_rev)
        assert (mine.sensor.columns_per_frame, mine.sensor.rows) == (info.w, info.h)
        assert mine.sensor.profile == str(info.format.udp_profile_lidar).split(".")[-1]
        np.testing.assert_array_equal(mine.sensor.pixel_shift_by_row, info.format.pixel_shift_by_row)
        np.testing.assert_array_equal(mine.sensor.beam_altitude_deg, info.beam_altitude_angles)
        np.testing.assert_array_equal(mine.sensor.beam_azimuth_deg, info.beam_azimuth_angles)


@pytest.mark.crosscheck
def test_osf_xyz_equals_ouster_sdk():
    """The points of an OSF frame: ouster-sdk's XYZ table of the stored metadata, applied to the stored range."""
    core = pytest.importorskip("ouster.sdk.core")
    path = external("ouster-sdk/single_scan_016.osf")
    theirs, infos = sdk_osf(path)
    (ours,) = list(lidarpkt.open(path))
    lut = core.XYZLut(infos[0], use_extrinsics=False)
    np.testing.assert_allclose(ours.xyz()[0], lut(theirs[0].field("RANGE")), rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", DAMAGED)
def test_damaged_osf_is_one_clear_error(name, tmp_path):
    path = external("ouster-sdk/" + name)
    with pytest.raises(CaptureFormatError, match="damaged OSF file") as info:
        list(lidarpkt.open(path))
    assert str(path) in str(info.value)
    proc = subprocess.run([sys.executable, "-m", "lidarpkt", "decode", str(path), "-o", str(tmp_path / "x.npz")],
                          capture_output=True, text=True, timeout=120, cwd=REPO_ROOT)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "damaged OSF file" in lines[0] and name in lines[0], proc.stderr
    assert not (tmp_path / "x.npz").exists()


def test_damaged_osf_says_what_is_wrong():
    with pytest.raises(CaptureFormatError, match="CRC-32"):
        list(lidarpkt.open(external("ouster-sdk/bad_crc32.osf")))
    with pytest.raises(CaptureFormatError, match=r"field \w+: a field image is neither PNG nor ZPNG"):
        list(lidarpkt.open(external("ouster-sdk/bad_encoding.osf")))


def test_empty_osf_gives_no_frame():
    with lidarpkt.open(external("ouster-sdk/empty_osf.osf")) as reader:
        assert list(reader) == []
        (sensor,) = reader.sensors()
    assert (sensor.model, sensor.serial) == ("OS-2-128", "992305000159")  # what its metadata says


def test_osf_is_no_packet_source():
    from lidarpkt.containers import open_packet_source

    with pytest.raises(UnsupportedContainerError, match="holds decoded frames, not packets"):
        open_packet_source(external("ouster-sdk/single_scan_016.osf"))


def test_packet_filters_are_refused_for_osf():
    from lidarpkt.errors import UnsupportedFilterError

    with pytest.raises(UnsupportedFilterError, match="ports="):
        lidarpkt.open(external("ouster-sdk/single_scan_016.osf"), ports=[7502])


def test_include_partial_and_workers():
    path = external("ouster-sdk/OS-0-128_v3.0.1_1024x10_20241017_141645.osf")
    every = list(lidarpkt.open(path))
    assert [f.partial for f in every] == [True, False, False]  # the recording starts in mid-frame
    whole = list(lidarpkt.open(path, include_partial=False))
    assert [f.frame_id for f in whole] == [f.frame_id for f in every[1:]]
    threaded = list(lidarpkt.open(path, workers=2))
    assert [f.frame_id for f in threaded] == [f.frame_id for f in every]
    for a, b in zip(threaded, every):
        np.testing.assert_array_equal(a.range_mm, b.range_mm)


def run_cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "lidarpkt", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO_ROOT)


def test_info_on_osf():
    path = external("ouster-sdk/OS-1-128_v2.3.0_1024x10_lb_n3.osf")
    proc = run_cli("info", path)
    assert proc.returncode == 0, proc.stderr
    head, sensor = proc.stdout.strip().splitlines()
    assert "OSF 2.1.0, 1 sensor, 3 frames" in head
    assert "OS-1-128 122201000998 (v2.3.0): RNG15_RFL8_NIR8, 1024 × 128, 3 frames, frame ids 1795–1797" in sensor
    doc = json.loads(run_cli("info", path, "--json").stdout)
    assert doc["format"] == "osf" and doc["frames"] == 3 and doc["sensors"][0]["partial_frames"] == 0
    empty = run_cli("info", external("ouster-sdk/empty_osf.osf"))
    assert empty.returncode == 0 and "0 frames" in empty.stdout
    bad = run_cli("info", external("ouster-sdk/bad_crc32.osf"))
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and "CRC-32" in bad.stderr


def test_decode_osf(tmp_path):
    path = external("ouster-sdk/OS-1-128_v2.3.0_1024x10_lb_n3.osf")
    frames = list(lidarpkt.open(path))
    assert run_cli("decode", path, "-o", tmp_path / "f.npz", "-q").returncode == 0
    with np.load(tmp_path / "f.npz") as npz:
        np.testing.assert_array_equal(npz["frame_id"], [f.frame_id for f in frames])
        np.testing.assert_array_equal(npz["range_mm"], np.stack([f.range_mm for f in frames]))
        np.testing.assert_array_equal(npz["near_ir"], np.stack([f.near_ir for f in frames]))
    proc = run_cli("decode", path, "-o", tmp_path / "f.mcap", "-q")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(run_cli("info", tmp_path / "f.mcap", "--json").stdout)
    assert info["udp_packets"] == 0  # no packets in an OSF: frames only
    from mcap.reader import make_reader

    with open(tmp_path / "f.mcap", "rb") as fh:
        topics = [ch.topic for _, ch, _ in make_reader(fh).iter_messages()]
    assert topics.count("/ouster/points") == 3


def test_export_osf(tmp_path):
    path = external("ouster-sdk/OS-1-128_v2.3.0_1024x10_lb_n3.osf")
    frames = list(lidarpkt.open(path))
    pq = pytest.importorskip("pyarrow.parquet")
    proc = run_cli("export", path, "-o", tmp_path / "pq", "--format", "parquet", "--workers", "1", "-q")
    assert proc.returncode == 0, proc.stderr
    table = pq.read_table(next((tmp_path / "pq").rglob("*.parquet")))
    assert table.num_rows == sum(int(np.count_nonzero(f.range_mm[:, :, f.column_valid])) for f in frames)


def test_analysis_reads_osf():
    path = external("ouster-sdk/single_scan_016.osf")
    (frame,) = list(lidarpkt.open(path))
    proc = run_cli("analyze", path, "--pixel", "60,500", "--return", "second_strongest", "--json")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout[proc.stdout.index("{"):])
    want = int(frame.range_mm[1][60, 500] > 0)  # the grid of an Ouster frame is its columns
    assert doc["frames"] == 1 and doc["pixels"][0]["n_returns"] == want


def test_view_osf(tmp_path):
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    pytest.importorskip("google.protobuf")
    from test_view_capture import check_frames, view_file

    path = external("ouster-sdk/OS-1-128_v2.3.0_1024x10_lb_n3.osf")
    frames = list(lidarpkt.open(path))
    client = view_file(tmp_path, path, "--rate", "4", frames_expected=len(frames), name="ouster",
                       labels=frames[0].return_labels)
    check_frames(client, frames, "ouster")


# ----------------------------------------------------------------------------- damage and hostile sizes


def _blocks(data: bytes) -> list[tuple[int, int]]:
    """(start, end) of every size-prefixed, CRC-ended block of an OSF file: header, chunks, metadata."""
    out, pos = [], 0
    header_end = 4 + struct.unpack_from("<I", data)[0] + 4
    out.append((0, header_end))
    (meta_offset,) = struct.unpack_from("<Q", data, _header_field_pos(data))
    pos = header_end
    while pos < meta_offset:
        end = pos + 4 + struct.unpack_from("<I", data, pos)[0] + 4
        out.append((pos, end))
        pos = end
    out.append((meta_offset, len(data)))
    return out


def _header_field_pos(data: bytes) -> int:
    """Where Header.metadata_offset (slot 2) lies, read from the header's vtable."""
    root = 4 + struct.unpack_from("<I", data, 4)[0]
    vtable = root - struct.unpack_from("<i", data, root)[0]
    return root + struct.unpack_from("<H", data, vtable + 4 + 2 * 2)[0]


def _recrc(data: bytearray, start: int, end: int) -> None:
    struct.pack_into("<I", data, end - 4, zlib.crc32(bytes(data[start:end - 4])))


def _mutants(data: bytes, n: int, seed: int):
    """``n`` damaged copies of an OSF file: flipped bytes (with the block's CRC made right again for most, so
    that the damage reaches the flatbuffers, the images and the sizes), huge 32-bit values, cuts."""
    rng = np.random.default_rng(seed)
    blocks = _blocks(data)
    for k in range(n):
        out = bytearray(data)
        start, end = blocks[int(rng.integers(len(blocks)))]
        kind = k % 4
        if kind == 3:
            yield bytes(out[: int(rng.integers(0, len(out)))])
            continue
        for _ in range(int(rng.integers(1, 8))):
            at = int(rng.integers(start, end - 4))
            if kind == 2 and at + 4 <= end - 4:
                struct.pack_into("<I", out, at, int(rng.choice([0xFFFFFFFF, 0x7FFFFFFF, 0x10000000, len(out) + 1])))
            else:
                out[at] ^= 1 << int(rng.integers(8))
        if kind != 0:
            _recrc(out, start, end)
        yield bytes(out)


@pytest.mark.parametrize("name,seed", [("single_scan_016.osf", 1), ("OS-1-128_v2.3.0_1024x10_lb_n3.osf", 2)])
def test_mutated_osf_raise_only_lidarpkt_errors(tmp_path, name, seed):
    """40 mutated copies of a good file: each reads to its end or raises a LidarpktError, within 10 s."""
    data = external("ouster-sdk/" + name).read_bytes()
    outcomes = {"read": 0, "refused": 0}
    for i, mutant in enumerate(_mutants(data, 40, seed)):
        path = tmp_path / f"m{i}.osf"
        path.write_bytes(mutant)
        t0 = time.monotonic()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                for frame in lidarpkt.open(path, include_partial=True):
                    assert frame.range_mm.shape[1:] == (frame.sensor.rows, frame.sensor.columns_per_frame)
            outcomes["read"] += 1
        except LidarpktError:
            outcomes["refused"] += 1
        assert time.monotonic() - t0 < 10, f"mutant {i} took {time.monotonic() - t0:.1f} s"
    assert outcomes["refused"] >= 10, outcomes  # the damage was seen, not only skipped over


def test_hostile_sizes_allocate_nothing_they_claim(tmp_path):
    """A chunk claiming 4 GiB, a vector claiming 2**32 - 1 items, a field shape claiming 2**40 pixels: each a
    clear error, with no allocation near what was claimed."""
    import tracemalloc

    data = external("ouster-sdk/single_scan_016.osf").read_bytes()
    (start, end) = _blocks(data)[1]
    cases = {}
    huge_chunk = bytearray(data)
    struct.pack_into("<I", huge_chunk, start, 0xFFFFFFF0)
    cases["chunk size"] = bytes(huge_chunk)
    from lidarpkt.containers.osf.format import root_table

    block = bytes(data[start:end - 4])
    chunk = root_table(block, "Chunk")
    msg_buf = chunk.messages[0].buffer
    base = np.frombuffer(block, np.uint8).ctypes.data
    msg_at = start + (np.frombuffer(msg_buf, np.uint8).ctypes.data - base)
    msg = root_table(bytes(msg_buf), "LidarScanMsg")
    # header_timestamp's vector length -> 0xFFFFFFFF
    slot_off = msg._t.Offset(4 + 2 * 2)
    vec = msg._t.Pos + slot_off
    vec += struct.unpack_from("<I", bytes(msg_buf), vec)[0]
    long_vector = bytearray(data)
    struct.pack_into("<I", long_vector, msg_at + vec, 0xFFFFFFFF)
    _recrc(long_vector, start, end)
    cases["vector length"] = bytes(long_vector)
    for what, mutant in cases.items():
        path = tmp_path / "h.osf"
        path.write_bytes(mutant)
        tracemalloc.start()
        try:
            with pytest.raises(CaptureFormatError):
                list(lidarpkt.open(path))
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 64 << 20, f"{what}: {peak / 1e6:.0f} MB"


def test_png_unfilter_matches_pillow():
    """The NumPy PNG unfiltering (the one used for 16-bit RGBA images, which Pillow reduces to 8 bits) on the
    8-bit RGBA and grey images of a real OSF file, every filter type among their rows, equals Pillow's."""
    import io

    from PIL import Image

    from lidarpkt.containers.osf.codecs import _png_inflate_unfilter

    data = external("ouster-sdk/OS-1-128_v2.3.0_1024x10_lb_n3.osf").read_bytes()
    pos, checked, filters = 0, 0, set()
    while (pos := data.find(b"\x89PNG\r\n\x1a\n", pos + 1)) >= 0:
        end = data.index(b"IEND", pos) + 8
        png = data[pos:end]
        width, height, depth, colour = struct.unpack_from(">IIBB", png, 16)
        bpp = {0: 1, 6: 4}[colour] * depth // 8
        with Image.open(io.BytesIO(png)) as img:
            want = np.asarray(img)
        want = want.astype(">u2").view(np.uint8) if depth == 16 else want
        got = _png_inflate_unfilter(png, height, width * bpp, bpp)
        np.testing.assert_array_equal(got, want.reshape(height, width * bpp))
        idat = zlib.decompress(b"".join(png[p + 8: p + 8 + struct.unpack_from(">I", png, p)[0]]
                                        for p in _chunks(png, b"IDAT")))
        filters |= set(np.frombuffer(idat, np.uint8).reshape(height, -1)[:, 0].tolist())
        checked += 1
    assert checked >= 6 and {1, 2, 3, 4} <= filters, filters  # Sub, Up, Average and Paeth rows all met


def _chunks(png: bytes, kind: bytes):
    pos = 8
    while pos + 8 <= len(png):
        length, k = struct.unpack_from(">I4s", png, pos)
        if k == kind:
            yield pos
        pos += 12 + length


def test_64_bit_field_image_round_trip():
    """A 64-bit field as ouster-sdk stores it (16-bit RGBA PNG, low bytes first in each pixel; rows with each
    filter) decodes to its values: the path Pillow cannot take."""
    from lidarpkt.containers.osf.codecs import decode_image

    rng = np.random.default_rng(7)
    h, w = 6, 40
    values = rng.integers(0, 2**63, (h, w), dtype=np.uint64)
    samples = values.astype("<u8").view(np.uint8).reshape(h, w, 4, 2)[..., ::-1].reshape(h, w * 8)  # big-endian 16-bit
    raw = bytearray()
    prev = np.zeros(w * 8, np.int16)
    for r in range(h):
        cur = samples[r].astype(np.int16)
        left = np.concatenate([np.zeros(8, np.int16), cur[:-8]])
        up_left = np.concatenate([np.zeros(8, np.int16), prev[:-8]])
        kind = r % 5
        if kind == 0:
            line = cur
        elif kind == 1:
            line = cur - left
        elif kind == 2:
            line = cur - prev
        elif kind == 3:
            line = cur - ((left + prev) >> 1)
        else:
            p = left + prev - up_left
            pa, pb, pc = np.abs(p - left), np.abs(p - prev), np.abs(p - up_left)
            line = cur - np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, prev, up_left))
        raw += bytes([kind]) + (line & 0xFF).astype(np.uint8).tobytes()
        prev = cur

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 6, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(bytes(raw))) + chunk(b"IEND", b""))
    np.testing.assert_array_equal(decode_image(png, (h, w), np.dtype("<u8"), None), values)
    np.testing.assert_array_equal(decode_image(png, (h, w), np.dtype("<i8"), None), values.view(np.int64))


# ----------------------------------------------------------------------------- files written here


def _built(messages_for, share_buffers=False):
    """An OSF file of the OS-0-32 sensor's metadata with the frame messages ``messages_for(h, w, shift)`` gives."""
    from osf_builder import osf_file

    from lidarpkt.vendors.ouster import load_metadata

    text = external("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json").read_text()
    md = load_metadata(text)
    return osf_file(text, messages_for(md.pixels_per_column, md.columns_per_frame, md.pixel_shift_by_row), share_buffers)


def _message(h, w, frame_id=5, **kw):
    from osf_builder import Message

    return Message(frame_id=frame_id, timestamp=10**18 + np.arange(w) * 97_656, measurement_id=np.arange(w),
                   status=np.ones(w), **kw)


@pytest.mark.crosscheck
def test_osf_written_here_reads_as_ouster_sdk_reads_it(tmp_path):
    """Fields in every encoding a reader meets (PNG of a destaggered channel, ZPNG of a staggered one, a raw
    1-D field, a ZPNG 64-bit field): ouster-sdk's reader and lidarpkt's give the same arrays."""
    from osf_builder import Custom, png_rgba, zpng

    from lidarpkt.core.grid import destagger

    rng = np.random.default_rng(3)

    def messages(h, w, shift):
        rng_mm = rng.integers(0, 2**20, (h, w), dtype=np.uint32)
        refl = rng.integers(0, 256, (h, w), dtype=np.uint8)
        return [_message(h, w, channels=[(1, 3, png_rgba(destagger(rng_mm, shift))), (5, 1, zpng(refl))], custom=[
            Custom("SCALARS", 2, (5,), np.arange(5, dtype="<u2").tobytes(), 4),
            Custom("WIDE", 4, (h, w), zpng(rng.integers(0, 2**63, (h, w), dtype=np.uint64)))])]

    path = tmp_path / "built.osf"
    path.write_bytes(_built(messages))
    (sdk,), _ = sdk_osf(path)
    (ours,) = list(lidarpkt.open(path))
    assert ours.frame_id == sdk.frame_id == 5
    np.testing.assert_array_equal(ours.range_mm[0], sdk.field("RANGE"))
    np.testing.assert_array_equal(ours.reflectivity[0], sdk.field("REFLECTIVITY"))
    np.testing.assert_array_equal(ours.extra["scalars"], sdk.field("SCALARS"))
    np.testing.assert_array_equal(ours.extra["wide"], sdk.field("WIDE"))
    np.testing.assert_array_equal(ours.column_timestamp_ns, sdk.timestamp.astype(np.int64))


def test_messages_sharing_one_buffer_are_refused(tmp_path):
    """Two frame messages pointing at one buffer (a few bytes decoding to a frame each time): an error."""
    from osf_builder import zpng

    def messages(h, w, shift):
        return [_message(h, w, frame_id=i, channels=[(5, 1, zpng(np.zeros((h, w), np.uint8)))]) for i in range(3)]

    path = tmp_path / "shared.osf"
    path.write_bytes(_built(messages, share_buffers=True))
    with pytest.raises(CaptureFormatError, match="share one buffer"):
        list(lidarpkt.open(path))
    path.write_bytes(_built(messages))  # the same messages, each with its own buffer: read
    assert [f.frame_id for f in lidarpkt.open(path)] == [0, 1, 2]


def test_fields_sharing_their_bytes_decode_to_a_bounded_size(tmp_path):
    """40 named 64-bit fields of a frame all pointing at one small ZPNG image: 320 B a pixel, refused before
    they are decoded (a frame's fields may decode to at most 256 B a pixel)."""
    from osf_builder import Custom, zpng

    def messages(h, w, shift):
        image = zpng(np.zeros((h, w), np.uint64))
        return [_message(h, w, custom=[Custom(f"F{i}", 4, (h, w), image) for i in range(40)], share_custom_data=True)]

    path = tmp_path / "fields.osf"
    path.write_bytes(_built(messages))
    assert path.stat().st_size < 20_000
    with pytest.raises(CaptureFormatError, match="256 B a pixel"):
        list(lidarpkt.open(path))
