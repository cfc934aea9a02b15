#!/usr/bin/env python3
"""PSNR and identical-pixel share of one run's PNG frames against another's.

    deploy/frame_psnr.py FRAMES TRUTH [--background R,G,B] [--csv FILE]

Compares every FRAMES/frame_NNNNN.png with TRUTH/frame_NNNNN.png (the same
camera) as common/image.cpp's measureQuality does: PSNR in dB over the RGB of
every pixel, and the share of identical RGB among the pixels off the
background in either frame (background default 0,0,0, the job's clear colour).
Prints one line per frame, then

    frames N: mean PSNR P dB over D differing frame(s) (I identical), mean identical share S %

The mean PSNR leaves out identical frames (infinite PSNR), as
pointillist-reference --quality does. --csv writes frame,psnr,covered,identical.

PNGs are read with libpng's simplified API through ctypes when libpng16 is
there (fast), else with zlib and numpy (8-bit RGB/RGBA/grey, no interlace).
"""
import argparse
import ctypes
import ctypes.util
import math
import pathlib
import struct
import sys
import zlib

import numpy as np


class _PngImage(ctypes.Structure):
    _fields_ = [("opaque", ctypes.c_void_p), ("version", ctypes.c_uint32),
                ("width", ctypes.c_uint32), ("height", ctypes.c_uint32),
                ("format", ctypes.c_uint32), ("flags", ctypes.c_uint32),
                ("colormap_entries", ctypes.c_uint32), ("warning_or_error", ctypes.c_uint32),
                ("message", ctypes.c_char * 64)]


def _load_libpng():
    for name in (ctypes.util.find_library("png16"), "libpng16.so.16"):
        if not name:
            continue
        try:
            lib = ctypes.CDLL(name)
            lib.png_image_begin_read_from_file.argtypes = [ctypes.POINTER(_PngImage), ctypes.c_char_p]
            lib.png_image_finish_read.argtypes = [ctypes.POINTER(_PngImage), ctypes.c_void_p,
                                                  ctypes.c_void_p, ctypes.c_int32, ctypes.c_void_p]
            lib.png_image_free.argtypes = [ctypes.POINTER(_PngImage)]
            return lib
        except OSError:
            continue
    return None


_LIBPNG = _load_libpng()
_PNG_IMAGE_VERSION = 1
_PNG_FORMAT_RGB = 2


def _read_libpng(path):
    image = _PngImage()
    image.version = _PNG_IMAGE_VERSION
    if not _LIBPNG.png_image_begin_read_from_file(ctypes.byref(image), str(path).encode()):
        raise ValueError(f"{path}: {image.message.decode(errors='replace')}")
    image.format = _PNG_FORMAT_RGB
    pixels = np.empty((image.height, image.width, 3), dtype=np.uint8)
    if not _LIBPNG.png_image_finish_read(ctypes.byref(image), None, pixels.ctypes.data, 0, None):
        message = image.message.decode(errors="replace")
        _LIBPNG.png_image_free(ctypes.byref(image))
        raise ValueError(f"{path}: {message}")
    return pixels


def _read_zlib(path):
    data = pathlib.Path(path).read_bytes()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG file")
    pos, idat, header = 8, [], None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    if header is None:
        raise ValueError(f"{path}: no IHDR chunk")
    width, height, depth, colour, _, _, interlace = header
    channels = {0: 1, 2: 3, 4: 2, 6: 4}.get(colour)
    if depth != 8 or channels is None or interlace != 0:
        raise ValueError(f"{path}: only 8-bit grey/RGB/RGBA PNGs without interlace are read here")
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), dtype=np.uint8)
    stride = width * channels
    rows = raw.reshape(height, stride + 1)
    out = np.zeros((height, stride), dtype=np.uint8)
    previous = np.zeros(stride, dtype=np.uint8)
    for y in range(height):
        kind, line = rows[y, 0], rows[y, 1:]
        if kind == 0:
            row = line.copy()
        elif kind == 1:  # Sub: a running sum per channel
            row = (np.cumsum(line.reshape(width, channels), axis=0, dtype=np.uint32) % 256)
            row = row.astype(np.uint8).reshape(stride)
        elif kind == 2:  # Up
            row = line + previous
        elif kind in (3, 4):  # Average, Paeth: byte by byte
            cur, up, filt = bytearray(stride), previous.tobytes(), line.tobytes()
            for i in range(stride):
                a = cur[i - channels] if i >= channels else 0
                b = up[i]
                if kind == 3:
                    cur[i] = (filt[i] + ((a + b) >> 1)) & 255
                else:
                    c = up[i - channels] if i >= channels else 0
                    p = a + b - c
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                    pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                    cur[i] = (filt[i] + pred) & 255
            row = np.frombuffer(bytes(cur), dtype=np.uint8)
        else:
            raise ValueError(f"{path}: row {y} has filter type {kind}")
        out[y] = row
        previous = row
    image = out.reshape(height, width, channels)
    if channels <= 2:
        return np.repeat(image[:, :, :1], 3, axis=2)
    return image[:, :, :3]


def read_rgb(path):
    """The PNG's pixels as an (height, width, 3) uint8 array, top row first."""
    return _read_libpng(path) if _LIBPNG is not None else _read_zlib(path)


def measure(frame, truth, background):
    """(psnr dB or inf, covered pixels, identical covered pixels), as measureQuality."""
    if frame.shape != truth.shape:
        raise ValueError(f"sizes differ: {frame.shape[1]}x{frame.shape[0]} against "
                         f"{truth.shape[1]}x{truth.shape[0]}")
    difference = frame.astype(np.int32) - truth.astype(np.int32)
    mse = float(np.mean(difference.astype(np.float64) ** 2))
    psnr = 10.0 * math.log10(255.0 * 255.0 / mse) if mse > 0.0 else math.inf
    covered = np.any(frame != background, axis=2) | np.any(truth != background, axis=2)
    same = np.all(difference == 0, axis=2)
    return psnr, int(np.count_nonzero(covered)), int(np.count_nonzero(covered & same))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("frames", type=pathlib.Path, help="directory of frame_NNNNN.png to rate")
    parser.add_argument("truth", type=pathlib.Path, help="directory of the frames to rate them against")
    parser.add_argument("--background", default="0,0,0", help="background RGB (default 0,0,0)")
    parser.add_argument("--csv", type=pathlib.Path, help="also write frame,psnr,covered,identical")
    args = parser.parse_args()
    background = np.array([int(v) for v in args.background.split(",")], dtype=np.uint8)
    if background.shape != (3,):
        parser.error("--background takes R,G,B")
    names = sorted(p.name for p in args.truth.glob("frame_*.png"))
    if not names:
        sys.exit(f"frame_psnr: no frame_*.png in {args.truth}")
    missing = [n for n in names if not (args.frames / n).is_file()]
    if missing:
        sys.exit(f"frame_psnr: {args.frames} lacks {len(missing)} frame(s) of {args.truth}, "
                 f"e.g. {missing[0]}")
    rows, psnrs, shares = [], [], []
    for name in names:
        psnr, covered, identical = measure(read_rgb(args.frames / name), read_rgb(args.truth / name),
                                           background)
        share = identical / covered if covered else 1.0
        rows.append((name, psnr, covered, identical))
        if not math.isinf(psnr):
            psnrs.append(psnr)
        shares.append(share)
        print(f"{name}: PSNR {psnr:.2f} dB, {100 * share:.2f} % of {covered} covered pixels identical")
    if args.csv:
        with open(args.csv, "w") as out:
            out.write("frame,psnr,covered,identical\n")
            for name, psnr, covered, identical in rows:
                out.write(f"{name},{psnr},{covered},{identical}\n")
    mean_psnr = sum(psnrs) / len(psnrs) if psnrs else math.inf
    print(f"frames {len(names)}: mean PSNR {mean_psnr:.2f} dB over {len(psnrs)} differing frame(s) "
          f"({len(names) - len(psnrs)} identical), mean identical share "
          f"{100 * sum(shares) / len(shares):.2f} %")


if __name__ == "__main__":
    main()
