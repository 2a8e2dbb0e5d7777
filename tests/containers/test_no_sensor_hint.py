"""Without fitting Ouster metadata, ``lidarpkt.open`` says which stream has the size of Ouster lidar packets
(read from the typed unrouted-stream key, not from its text) and what to give."""

from __future__ import annotations

import warnings

import pytest

import lidarpkt
from lidarpkt.errors import UnknownSensorError
from lidarpkt.core.streams import UnroutedStream
from conftest import external

PCAP = "ouster-sdk/OS-1-64_1024x10_fw20.pcap"  # legacy OS1-64: 12608-byte lidar packets


def _open_all(**options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with lidarpkt.open(external(PCAP), **options) as reader:
            list(reader)


def test_no_metadata_names_the_stream_and_the_flag():
    with pytest.raises(UnknownSensorError) as info:
        _open_all()
    text = str(info.value)
    assert "(12608 B), " in text and "has the size of Ouster lidar packets" in text and "--metadata" in text


def test_metadata_of_another_sensor_says_both_sizes():
    with pytest.raises(UnknownSensorError) as info:
        _open_all(metadata=external("ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.json"))
    text = str(info.value)
    assert "does not fit the stream" in text and "12608 B" in text


def test_unrouted_streams_are_typed_keys():
    reader = lidarpkt.open(external(PCAP))
    with pytest.raises(UnknownSensorError), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        list(reader)
    keys = list(reader.stats.unrouted_streams)
    assert keys and all(isinstance(k, UnroutedStream) for k in keys)
    assert {k.payload_size for k in keys} == {12608, 48}
    assert all(str(k) == f"{k.src} → {k.dst} ({k.payload_size} B)" for k in keys)
