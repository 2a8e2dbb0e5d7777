"""The per-block checks of Velodyne packets, made block by block (down the columns of an ``[N, 12]`` view),
give what the whole-array rules they replaced give: ``flags_ok`` (each block its bank's flag, unused blocks
unchecked, an azimuth of at most 36000), ``DataPackets.flag_ok``, the classifier's ``_velodyne_shaped`` and
``_is_hdl64e``, and ``known_return_mode`` (``np.isin`` of the return-mode bytes). Random batches of every model,
single, dual and mixed, with flags and azimuths drawn around the valid ones."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lidarpkt.vendors.velodyne.decode import DataPackets, decode_packets, flags_ok
from lidarpkt.vendors.velodyne.detect import _IS_BANK_FLAG, _is_hdl64e, _velodyne_shaped
from lidarpkt.vendors.velodyne.layout import packet_layout
from lidarpkt.vendors.velodyne.models import BANK_FLAGS, MODELS, RETURN_MODES
from lidarpkt.vendors.velodyne.packet import BLOCK_FLAG, known_return_mode


def _batch(rng: np.random.Generator, n: int, expected_rows: np.ndarray, modes: np.ndarray) -> SimpleNamespace:
    """Packets whose flags are mostly the expected ones, some a wrong bank or garbage; azimuths around 36000."""
    flag = expected_rows.copy()
    wrong = rng.random(flag.shape) < 0.03
    flag[wrong] = rng.choice([*BANK_FLAGS, 0, 0x1234, 0xFFFF], size=int(wrong.sum()))
    az = rng.integers(0, 36000, size=flag.shape)
    high = rng.random(flag.shape) < 0.02
    az[high] = rng.choice([36000, 36001, 65535], size=int(high.sum()))
    return SimpleNamespace(flag=flag.astype(np.uint16), azimuth_cdeg=az.astype(np.uint16),
                           return_mode=modes.astype(np.uint8))


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
@pytest.mark.parametrize("mix", ["strongest", "dual", "mixed"])
def test_flags_ok_is_the_whole_array_rule(model, mix):
    rng = np.random.default_rng(len(model.name) * 7 + len(mix))
    single, dual = packet_layout(model, "strongest").flag, packet_layout(model, "dual").flag
    n = 500
    is_dual = {"strongest": np.zeros(n, bool), "dual": np.ones(n, bool), "mixed": rng.random(n) < 0.5}[mix]
    expected = np.where(is_dual[:, None], dual[None, :], single[None, :])
    raw = _batch(rng, n, expected, np.where(is_dual, 0x39, 0x37))
    want = np.all(((raw.flag == expected) | (expected == 0)) & ((raw.azimuth_cdeg <= 36000) | (expected == 0)), axis=1)
    assert 0 < np.count_nonzero(want) < n  # both kinds of packet are there
    np.testing.assert_array_equal(flags_ok(raw, model), want)


def test_flag_ok_shaped_and_hdl64e_are_the_whole_array_rules():
    rng = np.random.default_rng(5)
    n = 800
    hdl = np.array([BANK_FLAGS[b % 2] for b in range(12)])
    rows = np.where((rng.random(n) < 0.5)[:, None], hdl[None, :], np.full(12, BLOCK_FLAG)[None, :])
    raw = _batch(rng, n, rows, rng.choice([*RETURN_MODES, 0, 0x3A], size=n))
    packets = SimpleNamespace(flag=raw.flag, azimuth_cdeg=raw.azimuth_cdeg)
    want_ok = np.all((raw.flag == BLOCK_FLAG) & (raw.azimuth_cdeg <= 36000), axis=1)
    np.testing.assert_array_equal(DataPackets.flag_ok.fget(packets), want_ok)
    want_shaped = (raw.flag[:, 0] == BANK_FLAGS[0]) & np.all(_IS_BANK_FLAG[raw.flag[:, :8]], axis=1) & (
        raw.azimuth_cdeg[:, 0] <= 36000)
    np.testing.assert_array_equal(_velodyne_shaped(raw), want_shaped)
    np.testing.assert_array_equal(_is_hdl64e(raw), np.all(raw.flag == hdl, axis=1))
    assert 0 < np.count_nonzero(_is_hdl64e(raw)) < n and 0 < np.count_nonzero(want_ok) < n
    np.testing.assert_array_equal(known_return_mode(raw.return_mode), np.isin(raw.return_mode, list(RETURN_MODES)))
    # no packet of the HDL-64E pattern: the block-by-block check stops early and says so for every packet
    vlp = SimpleNamespace(flag=np.full((50, 12), BLOCK_FLAG, np.uint16))
    assert not _is_hdl64e(vlp).any()


def test_the_checks_on_real_packet_views():
    """The strided views of real payload rows, one block's flag and another's azimuth spoiled."""
    from lidarpkt.containers.pcap_reader import read_batches

    from conftest import REPO_ROOT

    batches = read_batches(REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "vlp16-strongest.pcap")
    payload = np.concatenate([b.payload for b in batches if b.payload_size == 1206])
    payload[3, 100 * 5] = 0x00  # block 5's flag of packet 3
    payload[7, 100 * 9 + 2 : 100 * 9 + 4] = 0xFF  # block 9's azimuth of packet 7: 65535
    raw = decode_packets(payload, copy=False)
    want = np.all((raw.flag == BLOCK_FLAG) & (raw.azimuth_cdeg <= 36000), axis=1)
    assert np.flatnonzero(~want).tolist() == [3, 7]
    np.testing.assert_array_equal(raw.flag_ok, want)
    np.testing.assert_array_equal(flags_ok(raw, MODELS[0]), want)
