"""One Ouster frame being filled from its packets (:class:`FrameBuilder`): its pixels scattered by
measurement id, with the compiled kernel or its NumPy twin, and its per-column arrays."""

from __future__ import annotations

import numpy as np

from lidarpkt.core import kernels
from lidarpkt.core.frame import FrameCounters
from .profiles import HEADER_STATUS_FIELDS
from .decode import OusterPacketFields, packet_view
from .fieldplan import SLOT_ATTRS, extract, field_plan, new_fields, packet_layout, scatter_steps
from .metadata import OusterMetadata

_BLOCK_BYTES = 200_000  # packets copied into the word planes at a time (fits a 512 KB L2 cache)
_NATIVE_PIXEL_BYTES = 16  # ouster_scatter's widest pixel (MAX_WORDS words); wider ones take the NumPy twin


class FrameBuilder:
    """One frame being filled.

    With the compiled kernels, each packet's pixels are scattered straight into the frame's field
    arrays at their (row, column) place (``ouster_scatter``, no transposed copy). The NumPy twin
    scatters the raw pixel words by measurement id into word planes (``planes[k, row, column]`` =
    32-bit word k of the pixel) and extracts the fields once, when the frame is released, each by
    one contiguous shift/mask pass over its plane.

    Neither is zeroed up front: columns that never arrived are zeroed at release.
    """

    def __init__(self, md: OusterMetadata, key: tuple[int, int], frame_id: int, spare_planes: np.ndarray | None) -> None:
        """``spare_planes``: the word planes of a released frame, reused (the NumPy path), or ``None``."""
        h, w = md.pixels_per_column, md.columns_per_frame
        self.key = key
        self.frame_id = frame_id
        self.native = kernels.native if md.profile.pixel_bytes <= _NATIVE_PIXEL_BYTES else None
        self.planes: np.ndarray | None = None  # NumPy path: the packets' pixel words, one plane per word
        self.outputs: dict[str, np.ndarray | None] | None = None  # compiled path: the fields themselves
        if self.native is not None:
            self.outputs, self.targets = new_fields(md.profile, h, w)
        else:
            # scratch reused frame after frame (fresh 1.5 MB planes per OS-2-128 frame page-faulted)
            self.planes = spare_planes if spare_planes is not None else np.empty(
                (md.profile.pixel_bytes // 4, h, w), np.uint32)
        self.timestamp_ns = np.zeros(w, np.int64)
        self.measurement_id = np.zeros(w, np.uint16)
        self.status = np.zeros(w, np.uint32)
        self.encoder_count = np.zeros(w, np.uint32) if md.profile.legacy else None
        self.received = np.zeros(w, bool)
        self.header_status = None if md.profile.legacy else dict(
            zip(HEADER_STATUS_FIELDS, np.zeros((len(HEADER_STATUS_FIELDS), w), np.uint8)))
        self.counters = FrameCounters()
        self.last_mid0 = -1
        self.packets = 0  # packets placed
        self.host_ns = [0, 0]  # first and last capture time of its packets (0: unknown)

    def add(self, f: OusterPacketFields, payload: np.ndarray, md: OusterMetadata) -> None:
        """Columns of packets ``f`` with their payloads ``uint8[n, packet_size]``."""
        mids = f.measurement_id
        n, c = mids.shape
        flat = mids.ravel().astype(np.intp)
        if flat.size == 0:  # every packet was a duplicate
            return
        if self.outputs is not None and self.native is not None:
            self.native.ouster_scatter(payload, *packet_layout(md.profile, md.pixels_per_column, c), md.pixels_per_column,
                                       mids.astype(np.int64), scatter_steps(md.profile), self.targets)
        else:
            self._add_words(packet_view(payload, md.profile, md.pixels_per_column, c)["columns"]["pixels"], flat)
        self.timestamp_ns[flat] = f.timestamp_ns.ravel()
        self.measurement_id[flat] = mids.ravel()
        self.status[flat] = f.status.ravel()
        if self.encoder_count is not None and f.encoder_count is not None:  # LEGACY
            self.encoder_count[flat] = f.encoder_count.ravel()
        if self.header_status is not None and HEADER_STATUS_FIELDS[0] in f.header:
            index = mids.astype(np.intp)
            for k, arr in self.header_status.items():
                arr[index] = f.header[k][:, None]
        self.received[flat] = True

    def _add_words(self, words: np.ndarray, flat: np.ndarray) -> None:
        """The NumPy twin of ``ouster_scatter``: pixel words ``<u4[n, C, H, words]`` into the planes."""
        n, c = words.shape[:2]
        m0 = int(flat[0])
        planes = self.planes
        assert planes is not None  # the NumPy path has them
        src = words.transpose(3, 2, 0, 1)  # [words, H, n, C] view of the packets
        if m0 + n * c <= planes.shape[2] and int(flat[-1]) == m0 + n * c - 1 and (np.diff(flat) == 1).all():
            # the common case: consecutive measurement ids, strided copies into slices of columns,
            # a few packets at a time so that the source block stays in cache (about 2x faster than
            # one copy of the whole batch, whose transposed walk misses the cache)
            nw, h = planes.shape[:2]
            step = max(1, _BLOCK_BYTES // max(1, words.strides[0]))
            for i in range(0, n, step):
                j = min(n, i + step)
                planes[:, :, m0 + i * c : m0 + j * c].reshape(nw, h, j - i, c)[...] = src[:, :, i:j]
        else:
            planes[:, :, flat] = src.reshape(planes.shape[0], planes.shape[1], n * c)  # last copy wins

    def fields(self, profile, kept: np.ndarray) -> dict[str, np.ndarray | None]:
        """Pixel fields by frame attribute: ``range_mm``, ``reflectivity``, ``flags``, ``signal``
        (``[R, H, W]``, ``None`` if the profile has no SIGNAL), ``near_ir`` and ``window``
        (``[H, W]``, window ``None`` if absent); zeros where ``kept`` (``bool[W]``) is False."""
        if self.outputs is not None:
            zero_missing(self.targets, kept)
            return self.outputs
        planes = self.planes
        assert planes is not None  # the NumPy path has them
        zero_missing([planes], kept)
        shape = planes.shape[1:]
        out: dict[str, np.ndarray | None] = {}
        for attr, per_slot, dtype in field_plan(profile):
            if not per_slot:
                out[attr] = None
            elif attr not in SLOT_ATTRS:
                out[attr] = extract(planes, per_slot[0], np.empty(shape, dtype))
            else:
                arr = np.empty((len(per_slot),) + shape, dtype)
                for r, step in enumerate(per_slot):
                    extract(planes, step, arr[r])
                out[attr] = arr
        return out


def zero_missing(arrays, received: np.ndarray) -> None:
    """Zero the columns (last axis) of ``arrays`` where ``received`` is False, run by run of columns: slices,
    cheaper than a boolean index over a whole frame (frames at segment ends miss many columns)."""
    if received.all():
        return
    edges = np.flatnonzero(np.diff(np.concatenate(([0], (~received).view(np.int8), [0]))))
    for a, b in zip(edges[::2].tolist(), edges[1::2].tolist()):
        for arr in arrays:
            arr[..., a:b] = 0
