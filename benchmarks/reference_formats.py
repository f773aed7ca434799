#!/usr/bin/python3
"""Reference figures for the camera formats: vectorised numpy decoders (the fast way to read these
files in Python) run on the files that evkit_formats_bench left in a folder, in the same hour.

    /usr/bin/python3 benchmarks/reference_formats.py /tmp/evkit-bench
"""
import struct
import sys

import lz4.frame
import numpy as np

from timing import best_of

folder = sys.argv[1] if len(sys.argv) > 1 else "/tmp/evkit-bench"


def skip_header(data, marker):
    pos = 0
    while data[pos:pos + 1] == marker:
        pos = data.index(b"\n", pos) + 1
    return pos


def read_aedat2():
    data = open(f"{folder}/formats.aedat2", "rb").read()
    words = np.frombuffer(data, dtype=">u4", offset=skip_header(data, b"#")).reshape(-1, 2)
    addr, t = words[:, 0], words[:, 1].astype(np.int64)
    dvs = (addr & 0x80000000) == 0
    addr = addr[dvs]
    return t[dvs], 239 - ((addr >> 12) & 0x3FF), 179 - ((addr >> 22) & 0x1FF), (addr >> 11) & 1


def read_dat():
    data = open(f"{folder}/formats.dat", "rb").read()
    rec = np.frombuffer(data, dtype="<u4", offset=skip_header(data, b"%") + 2).reshape(-1, 2)
    d = rec[:, 1]
    return rec[:, 0].astype(np.int64), d & 0x3FFF, (d >> 14) & 0x3FFF, d >> 28


def read_evt2():
    data = open(f"{folder}/formats.evt2", "rb").read()
    w = np.frombuffer(data, dtype="<u4", offset=skip_header(data, b"%"))
    kind = w >> 28
    high = np.where(kind == 8, w & 0x0FFFFFFF, 0).astype(np.int64)
    high = np.maximum.accumulate(high)  # the last TIME_HIGH before each word (no wrap in the file)
    cd = kind <= 1
    t = (high[cd] << 6) | ((w[cd] >> 22) & 63)
    return t, (w[cd] >> 11) & 0x7FF, w[cd] & 0x7FF, kind[cd]


def read_aedat4():
    data = open(f"{folder}/formats.aedat4", "rb").read()
    (length,) = struct.unpack_from("<I", data, 14)
    pos, parts = 18 + length, []
    while pos + 8 <= len(data):
        stream, size = struct.unpack_from("<iI", data, pos)
        if stream != 0:  # the data table or another stream
            break
        packet = lz4.frame.decompress(data[pos + 8:pos + 8 + size])
        # size prefix, root offset, then the table: its vtable's first field is the vector offset.
        root = 4 + struct.unpack_from("<I", packet, 4)[0]
        vtable = root - struct.unpack_from("<i", packet, root)[0]
        field = struct.unpack_from("<H", packet, vtable + 4)[0]
        vec = root + field + struct.unpack_from("<I", packet, root + field)[0]
        (n,) = struct.unpack_from("<I", packet, vec)
        parts.append(np.frombuffer(packet, dtype=[("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "u1"), ("pad", "V3")],
                                   count=n, offset=vec + 4))
        pos += 8 + size
    ev = np.concatenate(parts)
    return ev["t"], ev["x"], ev["y"], ev["p"]


for name, fn in (("AEDAT 4 (LZ4), lz4.frame + numpy", read_aedat4), ("AEDAT 2.0, numpy", read_aedat2),
                 ("EVT 2.0, numpy", read_evt2), ("DAT, numpy", read_dat)):
    seconds, cols = best_of(fn)
    print(f"{name:<36} {len(cols[0]) / seconds / 1e6:8.1f} M events/s  ({seconds * 1e3:6.0f} ms)")
