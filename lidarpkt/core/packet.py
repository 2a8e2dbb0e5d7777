"""Packets as every source yields them, one at a time or in same-stream batches.

A *stream* is the packets of one (source address:port → destination address:port)
pair with one payload size. Decoders work on :class:`PacketBatch` objects: many
payloads of one stream as a single 2-D ``uint8`` array, so that a whole batch is
decoded in one NumPy pass.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator, NamedTuple

import numpy as np


class Endpoint(NamedTuple):
    """A UDP endpoint: IPv4/IPv6 address as text, port number."""

    address: str
    port: int

    def __str__(self) -> str:
        host = f"[{self.address}]" if ":" in self.address else self.address
        return f"{host}:{self.port}"


@dataclass(frozen=True, slots=True)
class Packet:
    """One UDP datagram (fragments already reassembled).

    Attributes:
        timestamp_ns: host capture (receive) time, ns since the Unix epoch.
        src, dst: the UDP endpoints; ``None`` where the container does not record
            them (payloads stored in a ROS bag, raw payload files).
        payload: the UDP payload.
    """

    timestamp_ns: int
    src: Endpoint | None
    dst: Endpoint | None
    payload: bytes


@dataclass(slots=True)
class PacketBatch:
    """Consecutive packets of one stream, all with the same payload size.

    Attributes:
        src, dst: the stream's endpoints (``None`` when the container has none).
        timestamp_ns: ``int64[N]`` host capture times, ns since the Unix epoch.
        payload: ``uint8[N, L]`` payloads, C-contiguous rows.
        index: ``int64[N]`` position of each packet among all packets of the source
            (record order), so that batches of several streams can be merged back in
            capture order.
    """

    src: Endpoint | None
    dst: Endpoint | None
    timestamp_ns: np.ndarray
    payload: np.ndarray
    index: np.ndarray

    def __post_init__(self) -> None:
        if self.payload.ndim != 2 or self.payload.dtype != np.uint8:
            raise ValueError("PacketBatch.payload must be a 2-D uint8 array")
        n = self.payload.shape[0]
        if self.timestamp_ns.shape != (n,) or self.index.shape != (n,):
            raise ValueError("PacketBatch timestamp_ns and index must have one entry per payload row")

    def __len__(self) -> int:
        return int(self.payload.shape[0])

    @property
    def payload_size(self) -> int:
        """Bytes in each payload."""
        return int(self.payload.shape[1])

    def packets(self) -> Iterator[Packet]:
        """The batch as individual :class:`Packet` objects (for display and tests, not hot paths)."""
        for t, row in zip(self.timestamp_ns.tolist(), self.payload):
            yield Packet(int(t), self.src, self.dst, row.tobytes())

    def select(self, mask_or_indices: np.ndarray | slice) -> "PacketBatch":
        """A batch of the chosen rows (boolean mask, integer indices or a slice), same stream."""
        return PacketBatch(
            self.src,
            self.dst,
            self.timestamp_ns[mask_or_indices],
            self.payload[mask_or_indices],
            self.index[mask_or_indices],
        )

    @classmethod
    def from_payloads(
        cls,
        payloads: Iterable[bytes] | np.ndarray,
        timestamp_ns: Iterable[int] | np.ndarray | None = None,
        *,
        src: Endpoint | None = None,
        dst: Endpoint | None = None,
        first_index: int = 0,
    ) -> "PacketBatch":
        """Build a batch from same-size payloads (bytes objects or a ``uint8[N, L]`` array).

        ``timestamp_ns`` defaults to zeros. Raises ``ValueError`` if the payload sizes differ.
        """
        if isinstance(payloads, np.ndarray):
            array = np.ascontiguousarray(payloads, dtype=np.uint8)
        else:
            chunks = list(payloads)
            sizes = {len(p) for p in chunks}
            if len(sizes) > 1:
                raise ValueError(f"payloads of one batch must share a size, got sizes {sorted(sizes)}")
            size = sizes.pop() if sizes else 0
            array = np.frombuffer(b"".join(chunks), dtype=np.uint8).reshape(len(chunks), size)
        n = array.shape[0]
        times = np.zeros(n, np.int64) if timestamp_ns is None else np.asarray(timestamp_ns, dtype=np.int64)
        return cls(src, dst, times, array, np.arange(first_index, first_index + n, dtype=np.int64))

    @classmethod
    def concatenate(cls, batches: list["PacketBatch"]) -> "PacketBatch":
        """Join batches of one stream and payload size, in the order given."""
        if not batches:
            raise ValueError("concatenate needs at least one batch")
        first = batches[0]
        return cls(
            first.src,
            first.dst,
            np.concatenate([b.timestamp_ns for b in batches]),
            np.concatenate([b.payload for b in batches]),
            np.concatenate([b.index for b in batches]),
        )


def payload_rows(payload: np.ndarray | bytes, size: int | None, what: str) -> np.ndarray:
    """Packets as ``uint8[N, L]``: one packet (``uint8[L]``, bytes) becomes one row; ``size``: the only
    length ``L`` allowed (``None``: any).

    Raises:
        lidarpkt.errors.PacketFormatError: not ``uint8`` rows, or rows of another length (``what`` names
            the packets in the message: ``"Ouster IMU packets"``).
    """
    from lidarpkt.errors import PacketFormatError

    if isinstance(payload, (bytes, bytearray, memoryview)):
        payload = np.frombuffer(payload, np.uint8)
    arr = np.asarray(payload)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.dtype != np.uint8 or arr.ndim != 2 or (size is not None and arr.shape[1] != size):
        need = f"{size} bytes each" if size is not None else "a uint8[N, L] array"
        raise PacketFormatError(f"{what} must be {need}; got an array {arr.dtype}{list(arr.shape)}")
    return arr
