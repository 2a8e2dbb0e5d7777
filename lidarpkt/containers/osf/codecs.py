"""The images OSF stores a field of two or more dimensions in: PNG (8-bit grey, 16-bit grey, 8-bit RGBA
or 16-bit RGBA for 8/16/32/64-bit values; a standard channel's image is destaggered) or ZPNG (zstd over
byte deltas, staggered as is). Nothing is allocated from a size an image claims before it is checked
against the size the field needs."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np

from lidarpkt.core.grid import restagger
from .format import Damaged

_ZPNG_MAGIC = 0xFBF8
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_rows(data: bytes, rows: int, cols: int, depth: int, colour: int) -> np.ndarray:
    """The samples of a PNG image as ``uint8[rows, cols * bytes per pixel]``, big-endian samples as stored.

    Pillow decodes the 8-bit kinds and 16-bit grey exactly; it reduces 16-bit RGBA to 8 bits, so that
    one (64-bit fields) is inflated and unfiltered here.
    """
    if data[:8] != _PNG_SIGNATURE or len(data) < 33 or data[12:16] != b"IHDR":
        raise Damaged("a field image is neither PNG nor ZPNG")
    width, height, bit_depth, colour_type = struct.unpack_from(">IIBB", data, 16)
    if (width, height, bit_depth, colour_type) != (cols, rows, depth, colour):
        raise Damaged(f"a field image is {width}x{height} of {bit_depth}-bit samples (colour type {colour_type}); "
                      f"the field needs {cols}x{rows} of {depth}-bit (colour type {colour})")
    channels = {0: 1, 2: 3, 6: 4}[colour]
    pixel_bytes = channels * depth // 8
    if depth == 16 and channels == 4:
        return _png_inflate_unfilter(data, rows, cols * pixel_bytes, pixel_bytes)
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data), formats=["PNG"]) as img:
            img.load()
            arr = np.asarray(img)
    except Exception as exc:  # Pillow raises OSError, SyntaxError, ValueError, zlib.error ... on damaged data
        raise Damaged(f"a PNG field image does not decode ({type(exc).__name__}: {exc})") from None
    if depth == 16:  # grey, values as numbers: back to the big-endian bytes of the other kinds
        return arr.astype(">u2").view(np.uint8).reshape(rows, cols * 2)
    return arr.reshape(rows, cols * pixel_bytes)


def _png_inflate_unfilter(data: bytes, rows: int, stride: int, bpp: int) -> np.ndarray:
    """PNG chunks → IDAT inflated into exactly ``rows`` filtered scanlines → unfiltered ``uint8[rows, stride]``."""
    idat = []
    pos = 8
    while pos + 8 <= len(data):
        length, kind = struct.unpack_from(">I4s", data, pos)
        if kind == b"IDAT":
            idat.append(data[pos + 8 : pos + 8 + length])
        elif kind == b"IEND":
            break
        pos += 12 + length
    want = rows * (stride + 1)
    d = zlib.decompressobj()
    try:
        raw = d.decompress(b"".join(idat), want)
    except zlib.error as exc:
        raise Damaged(f"a PNG field image does not inflate: {exc}") from None
    if len(raw) != want:
        raise Damaged(f"a PNG field image inflates to {len(raw)} B where its size needs {want}")
    lines = np.frombuffer(raw, np.uint8).reshape(rows, stride + 1)
    out = np.zeros((rows + 1, stride), np.uint8)  # row 0: the zero line above the image
    for r in range(rows):
        kind, line, above = lines[r, 0], lines[r, 1:], out[r]
        if kind == 0:
            out[r + 1] = line
        elif kind == 1:
            out[r + 1] = np.cumsum(line.reshape(-1, bpp), axis=0, dtype=np.uint8).ravel()
        elif kind == 2:
            out[r + 1] = line + above
        elif kind in (3, 4):  # Average, Paeth: each byte needs its left neighbour's result (Python ints: no
            # NumPy call per pixel; only 16-bit RGBA images, Pillow decodes the others)
            up, cur, filt = above.tolist(), [0] * stride, line.tolist()
            for x in range(stride):
                a = cur[x - bpp] if x >= bpp else 0
                b = up[x]
                if kind == 3:
                    cur[x] = (filt[x] + ((a + b) >> 1)) & 0xFF
                    continue
                c = up[x - bpp] if x >= bpp else 0
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                cur[x] = (filt[x] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 0xFF
            out[r + 1] = cur
        else:
            raise Damaged(f"a PNG field image has the unknown filter type {kind}")
    return out[1:]


def _zpng_rows(data: bytes, rows: int, cols: int, pixel_bytes: int) -> np.ndarray:
    """A ZPNG image (8-byte header, zstd of per-row byte deltas, 3/4-byte pixels as colour planes) as
    ``uint8[rows, cols * pixel_bytes]``, little-endian samples."""
    import zstandard

    magic, width, height, channels, per_channel = struct.unpack_from("<HHHBB", data)
    if (width, height, channels * per_channel) != (cols % 65536, rows % 65536, pixel_bytes):
        raise Damaged(f"a ZPNG field image is {width}x{height} of {channels * per_channel} B pixels; the field needs "
                      f"{cols}x{rows} of {pixel_bytes} B")
    want = rows * cols * pixel_bytes
    try:
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data[8:])) as reader:
            raw = reader.read(want + 1)  # one byte more than needed tells a stream that holds more
    except zstandard.ZstdError as exc:
        raise Damaged(f"a ZPNG field image does not inflate: {exc}") from None
    if len(raw) != want:
        raise Damaged(f"a ZPNG field image inflates to {len(raw)}{'+' if len(raw) > want else ''} B where its size "
                      f"needs {want}")
    packed = np.frombuffer(raw, np.uint8)
    if pixel_bytes in (3, 4):  # planes y = b', u = g' - b', v = g' - r' (and a') of the deltas r', g', b', a'
        planes = packed.reshape(pixel_bytes, rows, cols)
        b = planes[0]
        g = planes[1] + b
        deltas = [g - planes[2], g, b] + ([planes[3]] if pixel_bytes == 4 else [])
        packed = np.stack(deltas, axis=-1)
    else:
        packed = packed.reshape(rows, cols, pixel_bytes)
    return np.cumsum(packed, axis=1, dtype=np.uint8).reshape(rows, cols * pixel_bytes)


def decode_image(data: bytes | memoryview, shape: tuple[int, ...], dtype: np.dtype, shift: np.ndarray | None) -> np.ndarray:
    """A field of ``shape`` (two or more dimensions) and ``dtype`` from its ZPNG or PNG image; a PNG of a
    standard channel is destaggered, so ``shift`` (``pixel_shift_by_row``) staggers it back."""
    data = bytes(data)
    rows = shape[0]
    cols = int(np.prod(shape[1:]))
    size = dtype.itemsize
    if size not in (1, 2, 4, 8):
        raise Damaged(f"a field of {dtype} ({size} B) cannot be stored as an image")
    if len(data) >= 8 and struct.unpack_from("<H", data)[0] == _ZPNG_MAGIC:
        samples = _zpng_rows(data, rows, cols, size)
        values = samples.view(f"<u{size}")
        shift = None  # ZPNG keeps the field as it is in the frame
    else:
        depth, colour = {1: (8, 0), 2: (16, 0), 4: (8, 6), 8: (16, 6)}[size]
        samples = _png_rows(data, rows, cols, depth, colour)
        if size == 2:
            values = samples.view(">u2")
        elif size == 8:  # RGBA of 16-bit samples, each sample's bytes swapped back: bytes 0..7 low to high
            values = samples.reshape(rows, cols, 4, 2)[..., ::-1].reshape(rows, cols * 8).copy().view("<u8")
        else:
            values = samples.view(f"<u{size}")
    out = np.ascontiguousarray(values, dtype=f"<u{size}").view(dtype.newbyteorder("<") if size > 1 else dtype)
    out = out.reshape(shape)
    if shift is not None and len(shape) == 2:
        out = restagger(out, shift)
    return out
