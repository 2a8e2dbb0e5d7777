"""The vendor registry (``lidarpkt.vendors.registry``): every vendor's record is complete and answers for
real captures; the one classifier, through ``lidarpkt info``, names every external capture's streams as
``info`` named them before the registry (pinned in ``tests/data/info_streams.json``); a sensor file is
told apart by its content, whatever its name; one given for no stream of the capture is reported."""

from __future__ import annotations

import importlib
import json
import warnings
from pathlib import Path

import pytest

import lidarpkt
from conftest import external, external_root
from lidarpkt.containers import rosmsgs
from lidarpkt.containers.magic import FRAME_CONTAINERS
from lidarpkt.core.dropped import DropCounts
from lidarpkt.core.packet import Endpoint
from lidarpkt.core.streams import StreamKind
from lidarpkt.core.vendor import Vendor
from lidarpkt.errors import MetadataError, UnusedSensorFileWarning, UsageError
from lidarpkt.vendors import registry

PINNED = Path(__file__).parent / "data" / "info_streams.json"

# a real capture of each vendor, and the sensor file it is decoded with
CAPTURES = {
    "velodyne": ("rust-lidar-utils/velodyne_example.pcap", "rust-lidar-utils/VLP16db.yaml"),
    "ouster": ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", "ouster-sdk/OS-1-64_sensor_config_reduced.json"),
    "hesai": ("nebula/hesai/xt32/1673400677802009732", "nebula/hesai/PandarXT32.csv"),
}


def test_every_vendor_has_a_complete_record():
    names = [v.name for v in registry.VENDORS]
    assert len(set(names)) == len(names) and set(CAPTURES) <= set(names)
    store = rosmsgs.typestore(registry.ros_definitions())
    for v in registry.VENDORS:
        assert isinstance(v, Vendor) and v.title and v.streams
        assert importlib.import_module(f"lidarpkt.vendors.{v.name}").VENDOR is v  # each package exports its record
        assert all(isinstance(k, StreamKind) and k.vendor == v.name for k in v.streams)
        assert len({k.name for k in v.streams}) == len(v.streams) and any(k.lidar for k in v.streams)
        assert all(registry.vendor(v.name).stream(k.name) == k for k in v.streams)
        for hook in (v.classify, v.describe, v.summary, v.counter, v.sensor_time_ns, v.drops, v.endpoints):
            assert callable(hook)
        assert set(v.ros.packet_topics) <= {k.name for k in v.streams}
        assert all(t.topic.name.startswith("/") and (t.encode or t.encode_rotation) for t in v.ros.packet_topics.values())
        assert v.ros.frames.frame_id and v.ros.frames.points.startswith("/") and v.ros.frames.images.startswith("/")
        assert all(msgtype in store.types for msgtype in v.ros.packets)  # every packet message is readable
        assert (v.ros.sensor_file_topic is None) == (v.ros.sensor_file_refusal is None)
        assert set(v.frame_files) <= FRAME_CONTAINERS
        if v.sensor_files is not None:
            assert v.sensor_files.what and v.sensor_files.needed_for in ("decoding", "xyz", "")
        if v.models is not None:
            assert v.models() and all(isinstance(m, str) for m in v.models())


@pytest.mark.parametrize("name", sorted(CAPTURES))
def test_every_record_answers_for_a_real_capture(name):
    capture, sensor_file = CAPTURES[name]
    v = registry.vendor(name)
    files = registry.load_sensor_files([external(sensor_file)])
    assert [f.vendor for f in files] == [name]
    setup = registry.setup(files)
    reader = registry.open_packets(external(capture))
    seen = set()
    for batch in reader.batches():
        match = registry.classify(batch, setup)
        assert match is not None and match.vendor == name and match.decodable and match.stream in v.streams
        src, dst = v.endpoints(match)
        assert isinstance(src, Endpoint) and isinstance(dst, Endpoint) and 0 < dst.port < 65536
        parts = registry.by_kind(batch, match)  # these vendors' batches hold one stream kind: the batch itself
        assert v.split is not None or (len(parts) == 1 and parts[0][0] is match and parts[0][1] is batch)
        details = v.describe(batch, setup)
        assert details is not None and details["kind"] and all(isinstance(b, str) for b in v.summary(details))
        if match.lidar and match.stream not in seen:
            counter = v.counter(batch, match)
            assert counter is not None and counter.update(batch.payload, batch.timestamp_ns).shape == (len(batch),)
            assert counter.count.packets == len(batch)
        seen.add(match.stream)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with lidarpkt.open(external(capture), metadata=[external(sensor_file)]) as frames:
            assert list(frames) and frames.decoders
            for key, decoder in frames.decoders.items():
                assert key[0] == name and isinstance(v.drops(decoder.stats), DropCounts)
            assert frames.drop_counts().total() == sum(v.drops(d.stats).total() for d in frames.decoders.values())


def test_the_one_classifier_names_every_external_captures_streams_as_info_did():
    """``info``'s ``stream_kind``, ``vendor`` and ``kind`` of every stream of every external capture (bare, and
    with the Ouster metadata of its golden case), as ``info`` gave them before the registry (two classifiers).
    One difference, deliberate: the zone-monitoring stream of ``imu_zm_no_lidar.pcap`` with its metadata is
    ``ouster_zone``, what ``lidarpkt.open`` routes it as; the former enum of stream kinds had none for it
    (``other``)."""
    from lidarpkt.pipeline.describe import describe_capture

    pinned = json.loads(PINNED.read_text())
    root = external_root()
    if not root.is_dir():
        external("SOURCES.md")  # skips, or fails in CI
    for key, want in pinned.items():
        rel, label = key.split("|")
        metadata = [str(root / m) for m in _golden_metadata(rel)] if label == "files" else []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            doc = describe_capture(root / rel, metadata)
        got = sorted([s["src"] or "", s["dst"] or "", s["payload_size"], s["stream_kind"], s["vendor"], s["kind"]]
                     for s in doc["streams"])
        assert got == want, key


def _golden_metadata(rel: str) -> list[str]:
    """The Ouster metadata JSONs of the golden case of a capture (what the pinned table was made with)."""
    import golden_outputs

    for name, files in golden_outputs.CASES.values():
        if name == f"ext:{rel}":
            return [f[4:] for f in files if f.endswith(".json")]
    return []


# --------------------------------------------------------------------------- sensor files
@pytest.mark.parametrize("rel, vendor", [
    ("ouster-sdk/OS-1-64_sensor_config_reduced.json", "ouster"),
    ("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json", "ouster"),
    ("nebula/hesai/PandarXT32.csv", "hesai"),
    ("nebula/hesai/Pandar40P.csv", "hesai"),
    ("rust-lidar-utils/VLP16db.yaml", "velodyne"),
    ("veloview/VLP-16.xml", "velodyne"),
])
def test_a_sensor_file_is_told_apart_by_its_content_not_its_name(rel, vendor, tmp_path):
    (f,) = registry.load_sensor_files([external(rel)])
    assert f.vendor == vendor and f.name == str(external(rel))
    renamed = tmp_path / "sensor.dat"  # no suffix says what it is
    renamed.write_bytes(external(rel).read_bytes())
    assert registry.load_sensor_files(str(renamed))[0].vendor == vendor
    again = registry.load_sensor_files([f.loaded])[0]  # a loaded file passes through
    assert again.vendor == vendor


@pytest.mark.parametrize("content, says", [
    ("id,name,price\n1,bolt,0.10\n2,nut,0.05\n", "comma-separated lines"),  # a CSV that is no Hesai file
    ("channel,elevation,azimuth\nx,y,z\n", "comma-separated lines"),
    ('{"type": "FeatureCollection", "features": []}', "a JSON dict"),  # a JSON that is no Ouster metadata
    ("[1, 2, 3]", "a JSON list"),
    ("lasers: not a list", "starts with"),
    ("", "empty"),
])
def test_a_file_of_no_known_kind_is_one_error_naming_it(content, says, tmp_path):
    path = tmp_path / "sensor.csv"
    path.write_text(content)
    with pytest.raises(MetadataError) as info:
        registry.load_sensor_files([path])
    text = str(info.value)
    assert text.startswith(f"{path}: not a sensor file lidarpkt reads") and says in text
    assert all(v.sensor_files.what in text for v in registry.VENDORS if v.sensor_files is not None)


def test_a_missing_sensor_file_says_so(tmp_path):
    with pytest.raises(MetadataError, match="no such file"):
        registry.load_sensor_files([tmp_path / "nope.json"])


def test_a_sensor_file_of_no_stream_of_the_capture_is_reported():
    with pytest.warns(UnusedSensorFileWarning, match="PandarXT32.csv: Hesai angle-correction CSV, but no stream"):
        frames = list(lidarpkt.open(external("rust-lidar-utils/velodyne_example.pcap"),
                                    metadata=[external("nebula/hesai/PandarXT32.csv")]))
    assert frames and frames[0].sensor.vendor == "velodyne"


def test_another_vendors_calibration_for_a_sensor_that_needs_its_own_is_an_error():
    """A Velodyne YAML given for a Hesai bag: the error names the file and the one the sensor takes, not a
    missing calibration of a PandarXT32 later."""
    with pytest.raises(MetadataError) as info:
        list(lidarpkt.open(external("nebula/hesai/xt32/1673400677802009732"),
                           metadata=[external("rust-lidar-utils/VLP16db.yaml")]))
    text = str(info.value)
    assert "VLP16db.yaml is a Velodyne calibration" in text and "takes a Hesai angle-correction CSV" in text
    assert "no calibration for" not in text


def test_several_sensor_files_each_to_its_own_sensor():
    """One Ouster metadata per sensor of one capture, each fitting its stream by the packets' identity."""
    base = "ouster-sdk/same_ports_nonlegacy"
    files = registry.load_sensor_files([external(f"{base}.1.json"), external(f"{base}.2.json")])
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnusedSensorFileWarning)
        warnings.simplefilter("ignore", DeprecationWarning)
        with lidarpkt.open(external(f"{base}.pcap"), metadata=files) as reader:
            serials = {f.sensor.serial for f in reader}
    assert serials == {f.loaded.serial for f in files} and len(serials) == 2


def test_an_unknown_model_is_one_error_naming_the_option():
    with pytest.raises(UsageError, match=r"^model='VLP-99': no such sensor model; give one of .*VLP-32A"):
        registry.check_model("VLP-99")
    registry.check_model("vlp 32a")  # case, spaces and dashes ignored
