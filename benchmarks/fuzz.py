"""Coverage-guided fuzzing (atheris / libFuzzer) of lidarpkt's parsers, for a bounded time.

    pip install '.[fuzz]'          # atheris: a dev tool, not a runtime dependency
    python benchmarks/fuzz.py --target pcap --seconds 180 [--corpus DIR] [--artifacts DIR] [--jobs 1]
    python benchmarks/fuzz.py --target all --seconds 120
    python benchmarks/fuzz.py --target pcap --replay tests/data/fuzz/pcap-*.bin   # re-run saved inputs

Targets (each checks more than "does not crash"):

- ``pcap``: the input is a capture file. Only ``lidarpkt.errors`` exceptions and ``LidarpktWarning``s
  may come out, and the chunked fast path (``batches()``, 4096 records a chunk) must give exactly the
  packets of the record-by-record path (``packets()`` with ``batch_packets=1``).
- ``reassembly``: the input is a script of fragments (key, offset, more flag, length, timestamp) for a
  small :class:`~lidarpkt.containers.reassembly.Reassembler`; its pending datagrams and held bytes stay within the
  bounds, the held-byte count is the bytes actually held, and every byte of a datagram it returns is a byte
  sent for that key at that offset.
- ``velodyne``: the input is cut into 1206-byte data packets and a 512-byte position packet, fed in
  batches to :class:`~lidarpkt.vendors.velodyne.VelodyneDecoder`; also ``parse_nmea`` of the text. Frames must
  have consistent shapes; every packet is counted.
- ``ouster``: the first byte picks a real metadata file (every profile), the rest is cut into lidar
  packets of its size for :class:`~lidarpkt.vendors.ouster.OusterDecoder`; frames must have consistent shapes.
- ``metadata``: the input is an Ouster metadata JSON for ``load_metadata``; a metadata it accepts must
  also build a decoder and decode a packet of its own size.
- ``hesai``: the first byte picks a Pandar model (bits 0-2) and whether the decoder is told it or detects
  it (bit 3), the second the batch length; the rest is cut into packets of the model's size and pushed
  to :class:`~lidarpkt.vendors.hesai.HesaiDecoder` (with a calibration of the model's channels), and described
  by ``describe_stream``. Every packet is counted (decoded, malformed, duplicate or late); frames have
  the model's rows, 1-3 slots and one azimuth and time per column; XYZ is finite.
- ``bags``: the first byte picks the container (see :func:`bag_files`): an ``.mcap`` file, a ROS 1 ``.bag``,
  a rosbag2 sqlite3 bag (opened by its ``.db3`` or its directory) or a rosbag2 directory with MCAP
  storage; for the rosbag2 kinds the input also carries the ``metadata.yaml``. ``BagReader.batches()``
  is read to the end: batch indices follow on, ``stats["packets"]`` counts them, ``recorded_sensor_file()`` is
  a JSON object or ``None``, no file stays open (also while a lidarpkt error is kept); then
  ``lidarpkt.open`` reads the same bag and routes as many packets.
- ``ouster-ros``: the ``bags`` target on bags as ouster-ros writes them (seeds: ROS 1 ``ouster_ros/PacketMsg``
  on ``/os_node0/*_packets``, ROS 2 ``ouster_sensor_msgs/msg/PacketMsg`` on ``/ouster/*``, the metadata after
  the first packets on ``<ns>/metadata``); also, when the bag holds metadata, no packet of its lidar or IMU
  size is left unrouted.
- ``osf``: the input is a flag byte and an OSF file for ``lidarpkt.open`` (seeds: small files written by
  ouster-sdk with its PNG and ZPNG encoders, when it is installed, and the empty one of its tests). Flag bit 0:
  the CRC-32 of every block is made right first (:func:`osf_with_crcs`), so that mutations reach the
  flatbuffers, the images and the sizes rather than stop at the CRC. Every frame has the shapes
  its sensor's metadata gives (``[R, H, W]`` pixels, ``[W]`` columns), ``stats.frames`` counts them, and
  ``lidarpkt info``'s description (read without decoding the fields) counts as many frames when both read
  the whole file.

Each target runs as libFuzzer processes of at most ``--segment`` seconds (60) on one corpus folder, one
after the other: under atheris the process RSS grows by tens of KB per execution (the same inputs in
plain Python keep a flat RSS), so a single long run would end on the RSS limit, not on a finding.
The last line gives the executions and findings of all segments.

Seeds come from the real captures in ``../shared/fixtures/external`` and the canned fixtures. A crash
writes the input under ``--artifacts`` (default ``benchmarks/fuzz-artifacts/``); keep each as a
regression test (``tests/data/fuzz/``). libFuzzer prints ``Done N runs in S second(s)`` at the end.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import struct
import sys
import tempfile
import time
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
EXTERNAL = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES", REPO.parent / "shared" / "fixtures" / "external"))

TARGETS = ("pcap", "reassembly", "velodyne", "ouster", "metadata", "bags", "hesai", "ouster-ros", "osf")
MAX_LEN = {"pcap": 70_000, "reassembly": 4096, "velodyne": 1206 * 4 + 600, "ouster": 70_000, "metadata": 16_384,
           "bags": 70_000, "hesai": 1266 * 5 + 2, "ouster-ros": 70_000, "osf": 70_000}


class Finding(AssertionError):
    """An invariant of a target does not hold (libFuzzer reports it as a crash)."""


def _import_lidarpkt(instrument: bool, target: str = ""):
    if instrument:
        import atheris

        # bags: the container parsers it drives (mcap, rosbags) are instrumented too, so that coverage
        # leads the mutations past their checks into the records lidarpkt reads
        third_party = ["mcap", "rosbags"] if target in ("bags", "ouster-ros") else ["flatbuffers"] if target == "osf" else []
        with atheris.instrument_imports(include=["lidarpkt"] + third_party):
            if "flatbuffers" in third_party:
                import flatbuffers.table  # noqa: F401
            if "mcap" in third_party:
                import mcap.reader  # noqa: F401
                import rosbags.highlevel  # noqa: F401
                import rosbags.rosbag1  # noqa: F401
                import rosbags.rosbag2  # noqa: F401
            import lidarpkt.vendors.hesai.frames  # noqa: F401
            import lidarpkt.containers.bags  # noqa: F401
            import lidarpkt.vendors.ouster  # noqa: F401
            import lidarpkt.vendors.ouster.osf  # noqa: F401
            import lidarpkt.containers.pcap_reader  # noqa: F401
            import lidarpkt.containers.reassembly  # noqa: F401
            import lidarpkt.pipeline.reader  # noqa: F401
            import lidarpkt.vendors.velodyne  # noqa: F401
    else:
        import lidarpkt.vendors.ouster  # noqa: F401
        import lidarpkt.containers.pcap_reader  # noqa: F401
        import lidarpkt.vendors.velodyne  # noqa: F401


def _guard(fn):
    """Run one input: lidarpkt errors are fine, lidarpkt warnings are ignored, anything else is a finding."""
    from lidarpkt.errors import LidarpktError, LidarpktWarning

    def run(data: bytes) -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a RuntimeWarning (overflow, NaN) or other warning is a finding
            warnings.simplefilter("ignore", LidarpktWarning)
            try:
                fn(data)
            except LidarpktError:
                pass

    return run


# ------------------------------------------------------------------------------------------ targets
def make_pcap_target():
    from lidarpkt.containers.pcap_reader import PcapReader

    path = os.path.join("/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir(), f"lidarpkt-fuzz-{os.getpid()}.pcap")

    def target(data: bytes) -> None:
        with open(path, "wb") as fh:
            fh.write(data)
        try:
            slow = PcapReader(path, batch_packets=1)
            a = list(slow.packets())
            fast = PcapReader(path)
            b = [p for batch in fast.batches() for p in batch.packets()]
        finally:
            os.unlink(path)  # libFuzzer ends the process with exit(): leave nothing behind
        key = lambda p: (p.timestamp_ns, p.src, p.dst, p.payload)  # noqa: E731
        if sorted(map(key, a)) != sorted(map(key, b)):
            raise Finding(f"batches() gave {len(b)} packets, record-by-record packets() {len(a)}, or different ones")
        if slow.stats.yielded != len(a):
            raise Finding("stats.yielded disagrees with the packets yielded")

    return target


def make_reassembly_target():
    import atheris

    from lidarpkt.containers.reassembly import FRAGMENT_OVERHEAD, Reassembler

    def pattern(key: int, offset: int, n: int, salt: int) -> bytes:
        return bytes(((key * 131 + salt * 17 + offset + i) * 7) & 0xFF for i in range(n))

    def target(data: bytes) -> None:
        fdp = atheris.FuzzedDataProvider(data)
        r = Reassembler(timeout_ns=1000, max_datagrams=4, max_bytes=12_000)
        ts = 0
        while fdp.remaining_bytes() > 0:
            key = fdp.ConsumeIntInRange(0, 5)
            salt = fdp.ConsumeIntInRange(0, 1)  # 1: the sender reused the IP ID for other bytes
            offset = fdp.ConsumeIntInRange(0, 8200) * 8 - fdp.ConsumeIntInRange(0, 1) * 3
            more = fdp.ConsumeBool()
            n = fdp.ConsumeIntInRange(0, 3000)
            ts += fdp.ConsumeIntInRange(0, 600)
            out = r.add(key, offset, more, pattern(key, offset, n, salt), ts)
            held = sum(len(p) + FRAGMENT_OVERHEAD for e in r._pending.values() for p in e.pieces.values())
            if held != r.held_bytes:
                raise Finding(f"held_bytes {r.held_bytes} but {held} bytes held")
            for e in r._pending.values():  # the incremental prefix is what a full sort finds
                covered = 0
                for o in sorted(e.pieces):
                    if o > covered:
                        break
                    covered = max(covered, o + len(e.pieces[o]))
                if covered != e.prefix or e.offsets != sorted(e.pieces):
                    raise Finding(f"contiguous prefix {e.prefix}, a full sort says {covered}")
            if r.pending_datagrams > r.max_datagrams:
                raise Finding(f"{r.pending_datagrams} datagrams pending, more than {r.max_datagrams}")
            if r.held_bytes > r.max_bytes and r.pending_datagrams > 1:
                raise Finding(f"{r.held_bytes} bytes held, more than {r.max_bytes}")
            if out is not None:
                # byte by byte, what some fragment sent for this key (a reused ID whose fragments
                # sit at different offsets cannot be told apart, in the kernel neither)
                a, b = pattern(key, 0, len(out), 0), pattern(key, 0, len(out), 1)
                if any(x != y and x != z for x, y, z in zip(out, a, b)):
                    raise Finding(f"datagram of key {key} ({len(out)} B) holds bytes never sent for it")
        r.flush()
        if r.pending_datagrams or r.held_bytes:
            raise Finding("flush left datagrams pending")

    return target


def make_velodyne_target():
    import numpy as np

    from lidarpkt.core.packet import PacketBatch
    from lidarpkt.vendors.velodyne import VelodyneDecoder
    from lidarpkt.core.nmea import parse_nmea

    def target(data: bytes) -> None:
        if len(data) < 4:
            return
        cut, step = data[0], 1 + data[1] % 4
        body = data[2:]
        pos = body[-512:] if cut & 1 and len(body) >= 512 else None
        if pos is not None:
            body = body[:-512]
            try:
                parse_nmea(pos[206:].split(b"\0")[0])
            except Exception as exc:  # NMEAError is a LidarpktError: re-raised below by _guard if not
                from lidarpkt.errors import LidarpktError

                if not isinstance(exc, LidarpktError):
                    raise
        n = len(body) // 1206
        payload = np.frombuffer(body[: n * 1206], np.uint8).reshape(n, 1206)
        host = (np.arange(n, dtype=np.int64) * 1_327_000 + 1_600_000_000_000_000_000) if cut & 2 else np.zeros(n, np.int64)
        dec = VelodyneDecoder(max_frame_columns=64 if cut & 4 else 8192)
        if pos is not None:
            dec.push_position(PacketBatch.from_payloads([pos], [1_600_000_000_000_000_000]))
        frames = []
        for i in range(0, n, step):
            frames += dec.push(PacketBatch.from_payloads(payload[i : i + step], host[i : i + step], first_index=i))
        frames += dec.finish()
        if dec.stats.packets != n:
            raise Finding(f"{n} packets pushed, {dec.stats.packets} counted")
        for f in frames:
            r, h, w = f.range_mm.shape
            if h != 16 or r not in (1, 2) or f.column_valid.shape != (w,) or f.azimuth_deg.shape != (w,):
                raise Finding(f"frame shapes {f.range_mm.shape} / {f.column_valid.shape}")
            f.xyz()

    return target


def make_hesai_target():
    import numpy as np

    from lidarpkt.vendors.hesai import HesaiCalibration, HesaiDecoder, describe_stream
    from lidarpkt.vendors.hesai.models import MODELS
    from lidarpkt.core.packet import PacketBatch

    def target(data: bytes) -> None:
        if len(data) < 3:
            return
        model = MODELS[data[0] % len(MODELS)]
        step = 1 + data[1] % 4
        size = model.sizes[(data[0] >> 4) % len(model.sizes)]
        body = data[2:]
        n = len(body) // size
        payload = np.frombuffer(body[: n * size], np.uint8).reshape(n, size)
        cal = HesaiCalibration(np.linspace(15, -25, model.channels), np.linspace(-3, 3, model.channels), "fuzz")
        dec = HesaiDecoder(model=None if data[0] & 8 else model, calibration=cal, max_frame_columns=64)
        host = np.arange(n, dtype=np.int64) * 500_000 + 1_600_000_000_000_000_000
        frames = []
        for i in range(0, n, step):
            batch = PacketBatch.from_payloads(payload[i : i + step], host[i : i + step], first_index=i)
            frames += dec.push(batch)
            describe_stream(batch)
        frames += dec.finish()
        st = dec.stats
        if st.packets != n or st.decoded_packets + st.malformed + st.duplicate_packets + st.late_packets != n:
            raise Finding(f"{n} packets pushed: {st}")
        for f in frames:
            r, h, w = f.range_mm.shape
            if h != model.channels or r not in (1, 2, 3) or f.azimuth_deg.shape != (w,) \
                    or f.column_timestamp_ns.shape != (w,) or f.pixel_time_offset_ns.shape != (h, w):
                raise Finding(f"frame shapes {f.range_mm.shape} / {f.azimuth_deg.shape}")
            if not np.isfinite(f.xyz()).all():
                raise Finding("XYZ not finite")

    return target


def _ouster_metadata_files() -> list[str]:
    files = [
        "ouster-sdk/OS-1-64_sensor_config_reduced.json",  # LEGACY 64
        "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json",  # dual 32, zero footer
        "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json",  # low data rate 128
        "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json",  # single 128
        "ouster-sdk/crc_test.json",  # low data rate, CRC, 512 columns
        "ouster-sdk/same_ports_nonlegacy.1.json",  # FUSA dual
        "ouster-sdk/empty_pcap.json",  # dual 128, CRC (33024 B)
        "ouster-sdk/OS-1-32-G_v2.1.1_1024x10.json",  # LEGACY 32
    ]
    return [str(EXTERNAL / f) for f in files]


def make_ouster_target():
    import numpy as np

    from lidarpkt.vendors.ouster import OusterDecoder, load_metadata
    from lidarpkt.core.packet import PacketBatch

    mds = [load_metadata(f) for f in _ouster_metadata_files()]

    def target(data: bytes) -> None:
        if len(data) < 2:
            return
        md = mds[data[0] % len(mds)]
        flags = data[1]
        body = data[2:]
        size = md.packet_size
        n = len(body) // size
        if n == 0:
            return
        payload = np.frombuffer(body[: n * size], np.uint8).reshape(n, size)
        dec = OusterDecoder(md, verify_crc=bool(flags & 1), soft_id_check=bool(flags & 2))
        frames = []
        step = 1 + (flags >> 2) % 3
        for i in range(0, n, step):
            frames += dec.push(PacketBatch.from_payloads(payload[i : i + step], np.arange(i, min(n, i + step)) + 1, first_index=i))
        frames += dec.finish()
        if dec.stats.packets != n:
            raise Finding(f"{n} packets pushed, {dec.stats.packets} counted")
        for f in frames:
            if f.range_mm.shape[1:] != (md.pixels_per_column, md.columns_per_frame):
                raise Finding(f"frame shape {f.range_mm.shape}")

    return target


def make_metadata_target():
    import numpy as np

    from lidarpkt.vendors.ouster import OusterDecoder, OusterGeometry, load_metadata
    from lidarpkt.core.packet import PacketBatch

    def target(data: bytes) -> None:
        try:
            doc = json.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
            return
        if not isinstance(doc, dict):
            return
        md = load_metadata(doc)
        size = md.packet_size
        OusterGeometry(md)
        dec = OusterDecoder(md)
        if size <= 1 << 20:
            dec.push(PacketBatch.from_payloads(np.zeros((1, size), np.uint8)))
        dec.finish()

    return target


BAG_KINDS = ("mcap", "ros1", "rosbag2-sqlite3", "rosbag2-mcap")


def bag_files(data: bytes) -> tuple[str, dict[str, bytes], str]:
    """An input of the ``bags`` target as files: ``(kind, {name: bytes}, name of the path to open)``.

    Byte 0 picks the kind (``BAG_KINDS[byte % 4]``). ``mcap`` and ``ros1``: the rest is ``b.mcap`` /
    ``b.bag``. The rosbag2 kinds: bytes 1-2 (little-endian) are the length of the ``metadata.yaml``
    that follows (0: no metadata.yaml, a bare ``.db3``), the rest is the storage file ``b_0.db3`` /
    ``b_0.mcap``; a sqlite3 bag is opened by its ``.db3`` if bit 2 of byte 0 is set, else by its folder.
    """
    kind = BAG_KINDS[data[0] % 4] if data else "mcap"
    if kind in ("mcap", "ros1"):
        name = "b.mcap" if kind == "mcap" else "b.bag"
        return kind, {name: data[1:]}, name
    n = int.from_bytes(data[1:3], "little")
    meta, body = data[3 : 3 + n], data[3 + n :]
    storage = "b_0.db3" if kind == "rosbag2-sqlite3" else "b_0.mcap"
    files = {storage: body} | ({"metadata.yaml": meta} if n else {})
    opened = storage if kind == "rosbag2-sqlite3" and (data[0] & 4 or not n) else "."
    return kind, files, opened


def bag_input(kind: str, files: dict[str, bytes], opened: str = ".") -> bytes:
    """The inverse of :func:`bag_files` (for seeds)."""
    sel = BAG_KINDS.index(kind) | (4 if opened != "." else 0)
    if kind in ("mcap", "ros1"):
        return bytes([sel]) + next(iter(files.values()))
    meta = files.get("metadata.yaml", b"")
    body = next(v for k, v in files.items() if k != "metadata.yaml")
    return bytes([sel]) + len(meta).to_bytes(2, "little") + meta + body


def _ouster_sized(stream, metadata_text: str) -> bool:
    """Is an unrouted stream (a ``lidarpkt.pipeline.reader.UnroutedStream``) of the lidar or IMU packet size of this
    metadata?"""
    from lidarpkt.vendors.ouster import load_metadata

    try:
        md = load_metadata(metadata_text)
    except Exception:  # metadata lidarpkt refuses (a LidarpktError was raised by lidarpkt.open then)
        return False
    return stream.payload_size in (md.packet_size, md.imu_packet_size)


def make_ouster_ros_target():
    return make_bags_target(ouster_routing=True)


def make_osf_target():
    import lidarpkt
    from lidarpkt.pipeline.describe import describe_capture

    path = os.path.join("/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir(), f"lidarpkt-fuzz-{os.getpid()}.osf")

    def target(data: bytes) -> None:
        if not data:
            return
        with open(path, "wb") as fh:
            fh.write(osf_with_crcs(data[1:]) if data[0] & 1 else data[1:])
        try:
            described = None
            try:
                described = describe_capture(path)["frames"]
            except lidarpkt.LidarpktError:
                pass
            n = 0
            with lidarpkt.open(path) as reader:
                for frame in reader:
                    s = frame.sensor
                    r, h, w = frame.shape
                    if (h, w) != (s.rows, s.columns_per_frame) or r not in (1, 2) or r != len(frame.return_labels):
                        raise Finding(f"frame of shape {frame.shape} for a sensor of {s.rows} x {s.columns_per_frame}")
                    for name in ("column_valid", "column_timestamp_ns", "azimuth_deg", "measurement_id", "status"):
                        if getattr(frame, name).shape != (w,):
                            raise Finding(f"{name} has the shape {getattr(frame, name).shape}, not ({w},)")
                    for name in ("reflectivity", "signal", "flags"):
                        arr = getattr(frame, name)
                        if arr is not None and arr.shape != frame.shape:
                            raise Finding(f"{name} has the shape {arr.shape}, not {frame.shape}")
                    n += 1
            if reader.stats.frames != n:
                raise Finding(f"stats.frames = {reader.stats.frames}, {n} frames yielded")
            if described is not None and described != n:
                raise Finding(f"info counts {described} frames, lidarpkt.open gave {n}")
        finally:
            os.unlink(path)  # libFuzzer ends the process with exit(): leave nothing behind

    return target


def osf_with_crcs(data: bytes) -> bytes:
    """``data`` with the CRC-32 after each block it can find (header; chunks up to the metadata offset the header
    names; metadata) made right: the file as it would be if the damage had been written with its CRCs."""
    import zlib

    from lidarpkt.containers.osf.format import root_table

    out = bytearray(data)

    def fix(start: int) -> int | None:
        if start + 4 > len(out):
            return None
        end = start + 4 + struct.unpack_from("<I", out, start)[0]
        if end + 4 > len(out):
            return None
        struct.pack_into("<I", out, end, zlib.crc32(bytes(out[start:end])))
        return end + 4

    pos = fix(0)
    if pos is None:
        return bytes(out)
    try:
        meta = int(root_table(bytes(out[: pos - 4]), "Header").metadata_offset)
    except Exception:  # not a header the reader would take: nothing more to repair
        return bytes(out)
    while pos is not None and pos < meta:
        pos = fix(pos)
    if meta < len(out):
        fix(meta)
    return bytes(out)


def make_bags_target(ouster_routing: bool = False):
    import shutil

    import numpy as np

    import lidarpkt
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import LidarpktError

    root = os.path.join("/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir(), f"lidarpkt-fuzz-{os.getpid()}-bags")

    def open_fds() -> dict[str, str]:
        out = {}
        for fd in os.listdir("/proc/self/fd") if os.path.isdir("/proc/self/fd") else ():
            try:
                out[fd] = os.readlink(f"/proc/self/fd/{fd}")
            except OSError:  # the listing's own descriptor, closed by now
                pass
        return out

    def target(data: bytes) -> None:
        if not data:
            return
        _, files, opened = bag_files(data)
        os.makedirs(root, exist_ok=True)
        fds = open_fds()
        error = None
        try:
            for name, body in files.items():
                Path(root, name).write_bytes(body)
            path = os.path.normpath(os.path.join(root, opened))
            reader = BagReader(path, messages=bag_messages())
            count = 0
            batches = reader.batches()
            try:
                for b in batches:
                    if (b.payload.ndim != 2 or b.payload.dtype != np.uint8 or len(b.timestamp_ns) != len(b)
                            or list(b.index) != list(range(count, count + len(b)))):
                        raise Finding(f"batch of shape {b.payload.shape}, {len(b.timestamp_ns)} times, index "
                                      f"{b.index[:3]}... after {count} packets")
                    count += len(b)
            finally:
                batches.close()
            if reader.stats["packets"] != count:
                raise Finding(f"stats['packets'] = {reader.stats['packets']}, {count} packets yielded")
            md = reader.recorded_sensor_file()
            if md is not None and not isinstance(json.loads(md), dict):  # callers hand it to load_metadata
                raise Finding(f"recorded_sensor_file() is {md[:40]!r}..., not a JSON object")
            if count or md is not None:
                fr = lidarpkt.open(path)
                try:
                    for _ in fr:
                        pass
                finally:
                    fr.close()
                if fr.stats.packets != count:
                    raise Finding(f"lidarpkt.open routed {fr.stats.packets} packets, BagReader gave {count}")
                if ouster_routing and md is not None:
                    left = {k: n for k, n in fr.stats.unrouted_streams.items() if _ouster_sized(k, md)}
                    if left:
                        raise Finding(f"packets of the bag's own Ouster sizes left unrouted: {left}")
        except LidarpktError as exc:
            error = exc  # kept, as a caller may keep it, while the open files are counted
        finally:
            shutil.rmtree(root, ignore_errors=True)  # libFuzzer ends the process with exit(): leave nothing behind
        if open_fds().keys() - fds.keys():
            import gc

            gc.collect()
            if left := {fd: name for fd, name in open_fds().items() if fd not in fds}:
                raise Finding(f"file descriptor(s) left open: {left}" + (f" after {error!r}" if error else ""))
        if error is not None:
            raise error

    return target


MAKERS = {
    "pcap": make_pcap_target,
    "reassembly": make_reassembly_target,
    "velodyne": make_velodyne_target,
    "ouster": make_ouster_target,
    "metadata": make_metadata_target,
    "bags": make_bags_target,
    "hesai": make_hesai_target,
    "ouster-ros": make_ouster_ros_target,
    "osf": make_osf_target,
}


# ------------------------------------------------------------------------------------------ seeds
def _bag_seeds() -> list[bytes]:
    """Small bags of every kind the reader opens, written with the official writers (``mcap_ros2``,
    ``rosbags``) from real packets: the nebula VLP-16 dual bag (also cut down to one 3-packet message,
    keeping its own old sqlite schema and metadata.yaml) and an OS-1-32 capture with its metadata."""
    import io
    import shutil
    import sqlite3

    import numpy as np
    from mcap_ros2.writer import Writer as McapWriter
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from lidarpkt.vendors.registry import ros_definitions
    from lidarpkt.containers.pcap_reader import read_packets

    def store(which):
        st = get_typestore(which)
        extra: dict = {}
        for name, text in ros_definitions().items():
            extra.update(get_types_from_msg(text, name))
        st.register(extra)
        return st

    ros2 = store(Stores.ROS2_HUMBLE)
    scan_t = "velodyne_msgs/msg/VelodyneScan"
    neb_dir = EXTERNAL / "nebula/vlp16/1673400471837873222"
    neb_db = neb_dir / "1673400471837873222_0.db3"
    vel: list[tuple[int, bytes]] = []
    if neb_db.exists():
        con = sqlite3.connect(f"file:{neb_db}?mode=ro", uri=True)
        raw = con.execute("SELECT data FROM messages ORDER BY timestamp LIMIT 1").fetchone()[0]
        con.close()
        scan = ros2.deserialize_cdr(raw, scan_t)
        vel = [(p.stamp.sec * 10**9 + p.stamp.nanosec, bytes(p.data)) for p in scan.packets[:3]]
    else:
        vel = [(1_600_000_000_000_000_000 + i * 1_327_000, bytes(1206)) for i in range(3)]
    os_md = EXTERNAL / "ouster-sdk/OS-1-32-G_v2.1.1_1024x10.json"
    os_cap = EXTERNAL / "ouster-sdk/OS-1-32-G_v2.1.1_1024x10.pcap"
    md_text, lidar, imu = "{}", bytes(6464), bytes(48)
    if os_md.exists() and os_cap.exists():
        md_text = os_md.read_text()
        for p in read_packets(os_cap):
            if len(p.payload) == 6464 and lidar == bytes(6464):
                lidar = p.payload
            elif len(p.payload) == 48:
                imu = p.payload
    t0 = vel[0][0]

    def ros_msgs(st, ros1: bool):
        """(topic, type, log time ns, message) of a mixed bag: VelodyneScan (one with packet stamps 0, read
        at the bag time), VelodynePacket, NebulaPacket (a position packet), ouster PacketMsg lidar and IMU,
        the Ouster metadata String and a topic of another type."""
        T = st.types
        time = lambda ns: T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)  # noqa: E731
        u8 = lambda b: np.frombuffer(b, np.uint8)  # noqa: E731
        hdr = (lambda ns: T["std_msgs/msg/Header"](seq=0, stamp=time(ns), frame_id="velodyne")) if ros1 else (
            lambda ns: T["std_msgs/msg/Header"](stamp=time(ns), frame_id="velodyne"))
        pkt = T["velodyne_msgs/msg/VelodynePacket"]
        out = [("/ouster/metadata", "std_msgs/msg/String", t0, T["std_msgs/msg/String"](data=md_text))]
        out += [("/velodyne_packets", scan_t, t, T[scan_t](header=hdr(t), packets=[pkt(stamp=time(t if i else 0), data=u8(d))]))
                for i, (t, d) in enumerate(vel)]
        out.append(("/velodyne_packet", "velodyne_msgs/msg/VelodynePacket", t0 + 1, pkt(stamp=time(0), data=u8(vel[0][1]))))
        out.append(("/velodyne_position", "nebula_msgs/msg/NebulaPacket", t0 + 2,
                    T["nebula_msgs/msg/NebulaPacket"](stamp=time(t0 + 2), data=u8(bytes(512)))))
        out.append(("/ouster/lidar_packets", "ouster_sensor_msgs/msg/PacketMsg", t0 + 3, T["ouster_sensor_msgs/msg/PacketMsg"](buf=u8(lidar))))
        out.append(("/ouster/imu_packets", "ouster_sensor_msgs/msg/PacketMsg", t0 + 4, T["ouster_sensor_msgs/msg/PacketMsg"](buf=u8(imu))))
        out.append(("/chatter", "std_msgs/msg/Int32", t0 + 5, T["std_msgs/msg/Int32"](data=7)))
        return out

    out: list[bytes] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        # MCAP files (the mcap_ros2 writer: zstd, lz4 and uncompressed chunks)
        for i, (compression, chunk) in enumerate((("zstd", 2000), ("lz4", 1 << 20), ("none", 1 << 20))):
            from mcap.writer import CompressionType

            fh = io.BytesIO()
            w = McapWriter(fh, chunk_size=chunk, compression=CompressionType[compression.upper()])
            schemas: dict = {}
            for topic, typ, t, msg in ros_msgs(ros2, False) if i < 2 else [m for m in ros_msgs(ros2, False) if "velodyne" in m[0]]:
                if typ not in schemas:
                    text, _ = ros2.generate_msgdef(typ, ros_version=2)
                    schemas[typ] = w.register_msgdef(typ, text)
                w.write_message(topic, schemas[typ], _ros_dict(msg), log_time=t, publish_time=t)
            w.finish()
            out.append(bag_input("mcap", {"b.mcap": fh.getvalue()}))
            if i == 0:
                out.append(bag_input("rosbag2-mcap", {"b_0.mcap": fh.getvalue(), "metadata.yaml": _rosbag2_yaml("mcap", ros_msgs(ros2, False))}))
        # ROS 1 bags (uncompressed, bz2 and lz4 chunks)
        ros1 = store(Stores.ROS1_NOETIC)
        for i, compression in enumerate((None, "BZ2", "LZ4")):
            path = tmpdir / f"r{i}.bag"
            w1 = Writer1(path)
            if compression:
                w1.set_compression(Writer1.CompressionFormat[compression])
            w1.open()
            conns: dict = {}
            for topic, typ, t, msg in ros_msgs(ros1, True):
                if topic not in conns:
                    conns[topic] = w1.add_connection(topic, typ, typestore=ros1)
                w1.write(conns[topic], t, ros1.serialize_ros1(msg, typ))
            w1.close()
            out.append(bag_input("ros1", {"b.bag": path.read_bytes()}))
        # rosbag2 sqlite3 (version 8, plain and with zstd-compressed messages)
        for i, mode in enumerate(("NONE", "MESSAGE")):
            path = tmpdir / f"s{i}"
            w2 = Writer2(path)
            w2.set_compression(Writer2.CompressionMode[mode], Writer2.CompressionFormat.ZSTD)
            w2.open()
            conns = {}
            for topic, typ, t, msg in ros_msgs(ros2, False):
                if topic not in conns:
                    conns[topic] = w2.add_connection(topic, typ, typestore=ros2)
                w2.write(conns[topic], t, ros2.serialize_cdr(msg, typ))
            w2.close()
            meta = (path / "metadata.yaml").read_bytes().replace(f"s{i}.db3".encode(), b"b_0.db3")
            out.append(bag_input("rosbag2-sqlite3", {"b_0.db3": (path / f"s{i}.db3").read_bytes(), "metadata.yaml": meta},
                                 opened="b_0.db3" if i else "."))
        # the real nebula bag (rosbag2 version 5: no message definitions inside), cut to one 3-packet message
        if neb_db.exists():
            db = tmpdir / "neb.db3"
            shutil.copy(neb_db, db)
            con = sqlite3.connect(db)
            first = con.execute("SELECT id, data FROM messages ORDER BY timestamp LIMIT 1").fetchone()
            scan = ros2.deserialize_cdr(first[1], scan_t)
            scan = type(scan)(header=scan.header, packets=scan.packets[:3])
            con.execute("DELETE FROM messages WHERE id != ?", (first[0],))
            con.execute("UPDATE messages SET data = ?", (ros2.serialize_cdr(scan, scan_t),))
            con.commit()
            con.execute("VACUUM")
            con.close()
            meta = (neb_dir / "metadata.yaml").read_bytes().replace(b"1673400471837873222_0.db3", b"b_0.db3")
            out.append(bag_input("rosbag2-sqlite3", {"b_0.db3": db.read_bytes(), "metadata.yaml": meta}))
            out.append(bag_input("rosbag2-sqlite3", {"b_0.db3": db.read_bytes()}, opened="b_0.db3"))  # no metadata.yaml
    return [s for s in out if len(s) <= MAX_LEN["bags"]]


def _ros_dict(msg):
    """A rosbags message as the nested dict the mcap_ros2 writer takes."""
    import numpy as np

    if isinstance(msg, np.ndarray):
        return msg.tobytes()
    if isinstance(msg, list):
        return [_ros_dict(m) for m in msg]
    if hasattr(msg, "__dataclass_fields__"):
        return {k: _ros_dict(getattr(msg, k)) for k in msg.__dataclass_fields__ if k != "__msgtype__"}
    return msg


def _rosbag2_yaml(storage: str, msgs) -> bytes:
    """A rosbag2 (version 8) metadata.yaml for ``b_0.STORAGE`` holding ``msgs`` (topic, type, time, msg)."""
    topics: dict[str, tuple[str, int]] = {}
    for topic, typ, _, _ in msgs:
        topics[topic] = (typ, topics.get(topic, (typ, 0))[1] + 1)
    times = [t for _, _, t, _ in msgs]
    lines = ["rosbag2_bagfile_information:", "  version: 8", f"  storage_identifier: {storage}",
             "  duration:", f"    nanoseconds: {max(times) - min(times)}", "  starting_time:",
             f"    nanoseconds_since_epoch: {min(times)}", f"  message_count: {len(msgs)}", "  topics_with_message_count:"]
    for topic, (typ, n) in topics.items():
        lines += ["    - topic_metadata:", f"        name: {topic}", f"        type: {typ}", "        serialization_format: cdr",
                  "        offered_qos_profiles: \"\"", "        type_description_hash: \"\"", f"      message_count: {n}"]
    lines += ['  compression_format: ""', '  compression_mode: ""', "  relative_file_paths:", f"    - b_0.{storage}",
              "  files: []", "  custom_data: {}", "  ros_distro: humble", ""]
    return "\n".join(lines).encode()


def seeds(target: str) -> list[bytes]:
    """Starting inputs from the real captures (and generated ones where none is small enough)."""
    out: list[bytes] = []
    if target == "pcap":
        from lidarpkt.core.packet import Endpoint, Packet
        from lidarpkt.writers.framing import frames_for
        from lidarpkt.writers.pcap import Interface, pcap_bytes, pcapng_bytes

        for rel in ("ouster-sdk/VLI-16-one-packet.pcap", "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10-single-packet.pcap",
                    "ouster-sdk/duplicate_id.pcap", "ouster-sdk/empty_pcap.pcap", "ouster-sdk/same_ports_nonlegacy.pcap",
                    "ouster-sdk/same_ports_legacy.pcap"):
            if (EXTERNAL / rel).exists():
                out.append((EXTERNAL / rel).read_bytes()[: MAX_LEN["pcap"]])
        vel = (EXTERNAL / "rust-lidar-utils/velodyne_example.pcap")
        if vel.exists():
            out.append(vel.read_bytes()[: 24 + 4 * (16 + 1248)])
        pk = [
            Packet(1_600_000_000_000_000_000, Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368), bytes(1206)),
            Packet(1_600_000_000_010_000_000, Endpoint("10.0.0.5", 7502), Endpoint("10.0.0.1", 7502), bytes(range(256)) * 12),
            Packet(1_600_000_000_020_000_000, Endpoint("fd00::5", 7502), Endpoint("fd00::1", 7502), bytes(range(200)) * 16),
        ]
        recs = [(p.timestamp_ns, f) for i, p in enumerate(pk) for f in frames_for(p, ident=i)]
        out.append(pcap_bytes(recs))
        out.append(pcap_bytes([(t, f) for t, f in recs], nanosecond=True, big_endian=True))
        vl = [(p.timestamp_ns, f) for i, p in enumerate(pk) for f in frames_for(p, ident=i, vlan=(3,), link="ethernet")]
        out.append(pcapng_bytes([(0, t, f) for t, f in vl], interfaces=[Interface("ethernet")]))
        sll = [(p.timestamp_ns, f) for i, p in enumerate(pk) for f in frames_for(p, ident=i, link="linux_sll2")]
        out.append(pcap_bytes(sll, link="linux_sll2"))
    elif target == "reassembly":
        out += [bytes(range(64)), bytes(64), b"\x01\x00\x00\x00\x01\x10\x00" * 10]
    elif target == "velodyne":
        rec = EXTERNAL / "einride-vlp16-go/recording.bin"
        if rec.exists():
            raw = rec.read_bytes()
            for k in range(0, 40, 10):
                out.append(bytes([6, 1]) + raw[k * 1206 : (k + 4) * 1206])
        from lidarpkt.containers.pcap_reader import read_packets

        cap = REPO / "fixtures/canned/vlp16-dual.pcap"
        if cap.exists():
            data, pos = [], None
            for p in read_packets(cap):
                if len(p.payload) == 512 and pos is None:
                    pos = p.payload
                elif len(p.payload) == 1206 and len(data) < 4:
                    data.append(p.payload)
                if pos is not None and len(data) == 4:
                    break
            out.append(bytes([3, 2]) + b"".join(data) + (pos or bytes(512)))
    elif target == "ouster":
        from lidarpkt.vendors.ouster import load_metadata
        from lidarpkt.containers.pcap_reader import read_packets

        sources = {  # metadata index -> a capture with its packets
            0: REPO / "fixtures/canned/os1-64-legacy.pcap",
            1: EXTERNAL / "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap",
            2: EXTERNAL / "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap",
            3: EXTERNAL / "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap",
            4: EXTERNAL / "ouster-sdk/crc_test.pcap",
            5: EXTERNAL / "ouster-sdk/same_ports_nonlegacy.pcap",
            7: EXTERNAL / "ouster-sdk/OS-1-32-G_v2.1.1_1024x10.pcap",
        }
        files = _ouster_metadata_files()
        for i, cap in sources.items():
            if not cap.exists() or not Path(files[i]).exists():
                continue
            size = load_metadata(files[i]).packet_size
            pk = []
            for p in read_packets(cap):
                if len(p.payload) == size:
                    pk.append(p.payload)
                    if len(pk) == 2 or size * (len(pk) + 1) > MAX_LEN["ouster"]:
                        break
            if pk:
                out.append(bytes([i, 1]) + b"".join(pk))
        out.append(bytes([6, 0]) + bytes(33024))
    elif target == "metadata":
        for f in sorted(glob.glob(str(EXTERNAL / "ouster-sdk/*.json")) + glob.glob(str(EXTERNAL / "rust-lidar-utils/*.json"))
                        + glob.glob(str(REPO / "fixtures/canned/os1-64-*.json"))):
            if "digest" in f or "truth" in f:
                continue
            text = Path(f).read_bytes()
            if len(text) <= MAX_LEN["metadata"]:
                out.append(text)
    elif target == "bags":
        out += _bag_seeds()
    elif target == "hesai":
        from lidarpkt.vendors.hesai.models import MODELS
        from lidarpkt.containers.bags import BagReader
        from lidarpkt.vendors.registry import bag_messages

        for bag in sorted(glob.glob(str(EXTERNAL / "nebula/hesai/*/*/metadata.yaml"))):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                batch = next(iter(BagReader(Path(bag).parent, messages=bag_messages()).batches()))
            i = next(k for k, m in enumerate(MODELS) if batch.payload_size in m.sizes)
            pick = MODELS[i].sizes.index(batch.payload_size) << 4
            k = max(1, min(4, MAX_LEN["hesai"] // batch.payload_size))
            out.append(bytes([i | pick, 1]) + batch.payload[:k].tobytes())
            out.append(bytes([i | pick | 8, 0]) + batch.payload[:k].tobytes())
    elif target == "ouster-ros":
        out += _ouster_ros_seeds()
    elif target == "osf":
        out += _osf_seeds()
    return out


def _ouster_ros_seeds() -> list[bytes]:
    """ouster-ros bags cut down from ``512x10_raw.bag`` (its metadata, 2 lidar and 2 IMU packets, the metadata
    recorded after the first packets as there): as ROS 1 (``ouster_ros/PacketMsg``) and as rosbag2 sqlite3
    (``ouster_sensor_msgs/msg/PacketMsg``)."""
    import numpy as np

    src = EXTERNAL / "ouster-sdk/512x10_raw.bag"
    if not src.exists():
        return []
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    kept, counts = [], {}
    with AnyReader([src]) as reader:
        for conn, t, raw in reader.messages():
            kind = conn.topic.rsplit("/", 1)[1]
            if counts.get(kind, 0) < (1 if kind == "metadata" else 2):
                counts[kind] = counts.get(kind, 0) + 1
                kept.append((conn, t, raw, reader.deserialize(raw, conn.msgtype)))
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        ros1 = Path(tmp, "b.bag")
        with Writer1(ros1) as w:
            conns = {}
            for conn, t, raw, _ in kept:
                if conn.topic not in conns:
                    conns[conn.topic] = w.add_connection(conn.topic, conn.msgtype, msgdef=conn.msgdef, md5sum=conn.digest)
                w.write(conns[conn.topic], t, raw)
        out.append(bag_input("ros1", {"b.bag": ros1.read_bytes()}))
        store = get_typestore(Stores.ROS2_HUMBLE)
        store.register(get_types_from_msg("uint8[] buf\n", "ouster_sensor_msgs/msg/PacketMsg"))
        bag2 = Path(tmp, "b2")
        with Writer2(bag2) as w:
            conns = {}
            for conn, t, _, msg in kept:
                topic = "/ouster/" + conn.topic.rsplit("/", 1)[1]
                if conn.msgtype == "std_msgs/msg/String":
                    typ, m = "std_msgs/msg/String", store.types["std_msgs/msg/String"](data=msg.data)
                else:
                    typ = "ouster_sensor_msgs/msg/PacketMsg"
                    m = store.types[typ](buf=np.asarray(msg.buf, np.uint8))
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, typ, typestore=store)
                w.write(conns[topic], t, store.serialize_cdr(m, typ))
        files = {p.name: p.read_bytes() for p in bag2.iterdir()}
        db3 = next(k for k in files if k.endswith(".db3"))
        out.append(bag_input("rosbag2-sqlite3", {"b_0.db3": files[db3], "metadata.yaml": files["metadata.yaml"].replace(
            db3.encode(), b"b_0.db3")}))
    return [x for x in out if len(x) <= MAX_LEN["ouster-ros"]]


def _osf_seeds() -> list[bytes]:
    """The empty OSF of ouster-sdk's tests, and one-frame files written by ouster-sdk (PNG and ZPNG encoders, a
    sparse RANGE, all other fields zero) when it is installed: small enough to mutate quickly."""
    out = []
    empty = EXTERNAL / "ouster-sdk/empty_osf.osf"
    if empty.exists():
        out += [b"\x00" + empty.read_bytes(), b"\x01" + empty.read_bytes()]
    meta = EXTERNAL / "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"
    try:
        import numpy as np
        from ouster.sdk import core, osf
    except ImportError:
        return out
    if not meta.exists():
        return out
    info = core.SensorInfo(meta.read_text())
    with tempfile.TemporaryDirectory() as tmp:
        for i, encoder in enumerate((osf.PngLidarFrameEncoder(1), osf.ZPngLidarFrameEncoder(1))):
            frame = core.LidarFrame(info)
            rng = np.random.default_rng(i)
            rng_field = frame.field("RANGE")
            rng_field[:] = 0
            rng_field[::4, ::8] = rng.integers(0, 200_000, rng_field[::4, ::8].shape)
            frame.timestamp[:] = 10**18 + np.arange(info.w) * 97_656
            frame.measurement_id[:] = np.arange(info.w)
            frame.status[:] = 1
            frame.frame_id = 7
            path = os.path.join(tmp, f"s{i}.osf")
            writer = osf.Writer(path, info, [], 0, osf.Encoder(encoder))
            writer.save(0, frame)
            writer.close()
            out += [b"\x00" + Path(path).read_bytes(), b"\x01" + Path(path).read_bytes()]
    return [x for x in out if len(x) <= MAX_LEN["osf"]]


# ------------------------------------------------------------------------------------------ main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--target", required=True, choices=TARGETS + ("all",))
    ap.add_argument("--seconds", type=int, default=60, help="fuzzing time per target")
    ap.add_argument("--corpus", help="corpus folder, kept between runs (default /tmp/lidarpkt-fuzz/corpus-TARGET)")
    ap.add_argument("--artifacts", default="/tmp/lidarpkt-fuzz/artifacts", help="where crash inputs go")
    ap.add_argument("--rss-limit-mb", type=int, default=1536)
    ap.add_argument("--replay", nargs="*", help="run these saved inputs once each (no fuzzing)")
    ap.add_argument("--segment", type=int, default=60,
                    help="restart libFuzzer on the same corpus every SEGMENT s: under atheris the process RSS grows "
                         "by tens of KB per execution (not in plain Python), so long single runs hit the RSS limit")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.target == "all":
        import subprocess

        rc = 0
        for t in TARGETS:
            cmd = [sys.executable, __file__, "--target", t, "--seconds", str(args.seconds), "--artifacts", args.artifacts,
                   "--rss-limit-mb", str(args.rss_limit_mb)]
            print("==>", " ".join(cmd), flush=True)
            rc |= subprocess.call(cmd)
        return rc

    if args.replay is not None:
        _import_lidarpkt(False)
        target = MAKERS[args.target]()
        run = _guard(target)
        for f in args.replay:
            run(Path(f).read_bytes())
            print(f"{f}: ok")
        return 0

    if not args.child:
        import re
        import subprocess

        runs = crashes = 0
        left = args.seconds
        t0 = time.monotonic()
        while left > 0:
            seg = min(args.segment, left)
            cmd = [sys.executable, __file__, "--child", "--target", args.target, "--seconds", str(seg), "--artifacts",
                   args.artifacts, "--rss-limit-mb", str(args.rss_limit_mb)] + (["--corpus", args.corpus] if args.corpus else [])
            proc = subprocess.run(cmd, stderr=subprocess.PIPE, text=True)
            sys.stderr.write(proc.stderr[-3000:])
            m = re.search(r"Done (\d+) runs", proc.stderr)
            runs += int(m.group(1)) if m else int((re.findall(r"number_of_executed_units: (\d+)", proc.stderr) or [0])[-1])
            if proc.returncode != 0:
                crashes += 1
                print(f"{args.target}: finding (exit {proc.returncode}); input saved under {args.artifacts}", flush=True)
                break
            left -= seg
        print(f"{args.target}: {runs} executions in {time.monotonic() - t0:.0f} s, {crashes} finding(s)", flush=True)
        return 1 if crashes else 0

    import atheris

    _import_lidarpkt(True, args.target)
    run = _guard(MAKERS[args.target]())
    corpus = args.corpus or f"/tmp/lidarpkt-fuzz/corpus-{args.target}"
    os.makedirs(corpus, exist_ok=True)
    for i, s in enumerate(seeds(args.target)):
        Path(corpus, f"seed-{i:03d}").write_bytes(s)
    artifacts = Path(args.artifacts)
    artifacts.mkdir(parents=True, exist_ok=True)
    lf_args = [
        sys.argv[0],
        f"-max_total_time={args.seconds}",
        f"-max_len={MAX_LEN[args.target]}",
        f"-rss_limit_mb={args.rss_limit_mb}",
        "-timeout=20",
        "-print_final_stats=1",
        f"-artifact_prefix={artifacts}/{args.target}-",
        corpus,
    ]
    print(f"fuzzing {args.target} for {args.seconds} s; corpus {corpus}; crash inputs -> {artifacts}/{args.target}-*", flush=True)
    atheris.Setup(lf_args, run)
    atheris.Fuzz()  # exits the process when the time is up or on a finding
    return 0


if __name__ == "__main__":
    sys.exit(main())
