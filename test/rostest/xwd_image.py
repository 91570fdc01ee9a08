"""Reads an X window dump (ZPixmap, 24/32 bits per pixel: Xvfb -fbdir, xwd -root) into a
numpy RGB array and writes PNG files, without extra dependencies."""
import struct
import zlib

import numpy as np


def read_xwd(path):
    with open(path, "rb") as f:
        data = f.read()
    header = struct.unpack(">25I", data[:100])
    header_size, _version, pixmap_format, depth, width, height = header[:6]
    byte_order, bits_per_pixel, bytes_per_line = header[7], header[11], header[12]
    red_mask, green_mask, blue_mask = header[14], header[15], header[16]
    ncolors = header[19]
    if pixmap_format != 2 or bits_per_pixel not in (24, 32):
        raise ValueError("unsupported xwd: format %d, %d bpp" % (pixmap_format, bits_per_pixel))
    offset = header_size + 12 * ncolors
    bpp = bits_per_pixel // 8
    raw = np.frombuffer(data, dtype=np.uint8, count=bytes_per_line * height, offset=offset)
    rows = raw.reshape(height, bytes_per_line)[:, :width * bpp].reshape(height, width, bpp)
    # Assemble each pixel as an integer in the dump's byte order, then apply masks.
    weights = [1 << (8 * i) for i in range(bpp)]
    if byte_order == 1:  # MSBFirst
        weights = weights[::-1]
    value = np.zeros((height, width), dtype=np.uint64)
    for i, w in enumerate(weights):
        value += rows[:, :, i].astype(np.uint64) * np.uint64(w)

    def channel(mask):
        shift = (mask & -mask).bit_length() - 1
        return ((value >> np.uint64(shift)) & np.uint64(mask >> shift)).astype(np.uint8)

    del depth
    return np.dstack([channel(red_mask), channel(green_mask), channel(blue_mask)])


def write_png(path, rgb):
    height, width, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].tobytes() for y in range(height))

    def chunk(tag, payload):
        return (struct.pack(">I", len(payload)) + tag + payload +
                struct.pack(">I", zlib.crc32(tag + payload) & 0xFFFFFFFF))

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(raw, 6)))
        f.write(chunk(b"IEND", b""))
