"""Helpers shared by the analysis tests (no tests here): FrameStacks built directly from arrays,
and the generated fixture scenes (written once per test session into a temporary folder)."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np

from lidarpkt.core.sequence import FrameStack
from lidarpkt.core.sensor import SensorInfo


def make_stack(range_mm, valid=None, labels=None, shift=None, reflectivity=None, vendor=None) -> FrameStack:
    """A FrameStack around ``range_mm`` ``[K, R, H, W]`` (mm, 0 = non-return)."""
    rng = np.asarray(range_mm, dtype=np.uint32)
    k, r, h, w = rng.shape
    labels = tuple(labels or (("strongest",) if r == 1 else ("last", "strongest")))
    vendor = vendor or ("ouster" if shift is not None else "velodyne")
    sensor = SensorInfo(
        vendor=vendor, model="test", rows=h, columns_per_frame=w, return_mode="dual" if r == 2 else labels[0],
        return_labels=labels, beam_altitude_deg=np.zeros(h), beam_azimuth_deg=np.zeros(h),
        pixel_shift_by_row=None if shift is None else np.asarray(shift),
    )
    return FrameStack(
        sensor=sensor, return_labels=labels, frame_id=np.arange(k, dtype=np.int64), range_mm=rng,
        reflectivity=np.zeros_like(rng, dtype=np.uint8) if reflectivity is None else np.asarray(reflectivity, np.uint8),
        column_valid=np.ones((k, w), bool) if valid is None else np.asarray(valid, bool),
        column_timestamp_ns=np.zeros((k, w), np.int64), azimuth_deg=np.zeros((k, w)),
    )


def destaggered_by_definition(img: np.ndarray, shift) -> np.ndarray:
    """destaggered[u, (c + shift[u]) % W] = staggered[u, c], written out pixel by pixel (reference)."""
    h, w = img.shape[-2:]
    out = np.empty_like(img)
    for u in range(h):
        for c in range(w):
            out[..., u, (c + shift[u]) % w] = img[..., u, c]
    return out


def ensure(name: str, **options) -> Path:
    """Path of a generated fixture capture (generated once and cached by ``fixtures.ensure``);
    skips the test when the fixture generator is not available."""
    import pytest

    fixtures = importlib.import_module("lidarpkt.fixtures")
    return fixtures.ensure(name, **options)


def load_fixture(name: str, **options):
    """(FrameStack of the complete frames, truth dict) of a generated capture."""
    from lidarpkt.analysis.stack import load_stack

    pcap = ensure(name, **options)
    meta = pcap.with_suffix(".json") if name.startswith("os1") else None
    return load_stack(pcap, metadata=meta), truth(pcap)


def truth(pcap: Path) -> dict:
    return json.loads(pcap.with_name(pcap.name.replace(".pcap", ".truth.json")).read_text())
