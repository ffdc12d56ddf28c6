#!/usr/bin/python3
"""Writes the seed corpus of fuzz/fits_input_fuzzer.cc into fuzz/corpus/.

Small valid and malformed FITS files covering what the input stage reads: plain images of
every BITPIX (with a spot, so that calibration gets past spot finding), a multi-extension
file with amplifier segments, a gzip file, tile-compressed images (RICE_1 with edge tiles,
RICE_1 quantized floats with dithering, GZIP_1, GZIP_2, and HCOMPRESS_1 / PLIO_1 which the
reader refuses), truncated or broken copies, and the inputs the first fuzzing campaign
found. Deterministic: the same bytes every run
(fixed seeds, gzip mtime 0), so that regenerating shows no diff. The whole corpus stays
under 300 KB.

Run with Debian's python3-numpy and python3-astropy (no pip):
    /usr/bin/python3 fuzz/make_corpus.py
"""

import gzip
import io
import os
import sys

import numpy as np
from astropy.io import fits

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "corpus")


def spot_frame(nx, ny, bias=1000.0, flux=2.0e4, sigma=0.9, seed=1):
    """A frame in ADU: bias, a Gaussian spot near the centre, Gaussian noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:ny, 0:nx]
    cx, cy = nx / 2 - 0.3, ny / 2 + 0.2
    spot = flux / (2 * np.pi * sigma**2) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2))
    return bias + spot + rng.normal(0.0, 3.0, size=(ny, nx))


def header_keys():
    h = fits.Header()
    h["GAIN"] = (2.0, "e-/ADU")
    h["RDNOISE"] = (6.0, "e-")
    h["PIXSIZE"] = (12.0, "um")
    h["EXPTIME"] = (1.0, "s")
    h["WAVELEN"] = (800.0, "nm")
    return h


def to_bytes(hdul):
    buffer = io.BytesIO()
    hdul.writeto(buffer)
    return buffer.getvalue()


def write(name, data):
    with open(os.path.join(OUT, name), "wb") as f:
        f.write(data)


def main():
    os.makedirs(OUT, exist_ok=True)
    for old in os.listdir(OUT):
        os.remove(os.path.join(OUT, old))

    frame = spot_frame(24, 20)
    # Plain images, one per BITPIX.
    plain = {
        "plain_u8.fits": np.clip(frame - 950, 0, 255).astype(np.uint8),
        "plain_u16.fits": frame.astype(np.uint16),  # BITPIX 16, BZERO 32768
        "plain_i32.fits": frame.astype(np.int32),
        "plain_f32.fits": frame.astype(np.float32),
        "plain_f64.fits": frame.astype(np.float64),
    }
    for name, data in plain.items():
        write(name, to_bytes(fits.HDUList([fits.PrimaryHDU(data, header=header_keys())])))
    i64 = fits.PrimaryHDU(frame.astype(np.int64), header=header_keys())
    write("plain_i64.fits", to_bytes(fits.HDUList([i64])))

    # BSCALE / BZERO / BLANK on 16-bit integers.
    scaled = fits.PrimaryHDU(frame.astype(np.int16) - 900, header=header_keys())
    scaled.header["BSCALE"] = 2.0
    scaled.header["BZERO"] = 100.0
    scaled.header["BLANK"] = -32768
    write("scaled_i16.fits", to_bytes(fits.HDUList([scaled])))

    # A test-stand file: empty primary, two amplifier segments with overscan.
    segments = [fits.PrimaryHDU(header=header_keys())]
    for k, name in enumerate(["AMP1", "AMP2"]):
        data = spot_frame(20, 16, seed=10 + k, flux=2.0e4 if k == 1 else 0.0).astype(np.uint16)
        hdu = fits.ImageHDU(data, name=name)
        hdu.header["DATASEC"] = "[5:20,1:16]"
        hdu.header["BIASSEC"] = "[1:4,1:16]"
        segments.append(hdu)
    write("mef_segments.fits", to_bytes(fits.HDUList(segments)))

    # gzip (mtime 0: the same bytes every run).
    write("plain_u16.fits.gz", gzip.compress(to_bytes(fits.HDUList([fits.PrimaryHDU(
        frame.astype(np.uint16), header=header_keys())])), compresslevel=9, mtime=0))

    # Tile-compressed images. astropy 5.2's tile_size is in FITS order (ZTILE1, ZTILE2).
    # 30 x 20 pixels in 16 x 8 tiles: tiles at the right and top edges are cut short.
    wide = spot_frame(30, 20, seed=3)
    compressed = {
        "rice_i16.fits": dict(data=wide.astype(np.int16), compression_type="RICE_1",
                              tile_size=(16, 8)),
        "rice_i32_rows.fits": dict(data=wide.astype(np.int32), compression_type="RICE_1"),
        "rice_u8.fits": dict(data=np.clip(wide - 950, 0, 255).astype(np.uint8),
                             compression_type="RICE_1", tile_size=(30, 4)),
        "rice_f32_dither.fits": dict(data=wide.astype(np.float32), compression_type="RICE_1",
                                     tile_size=(30, 5), quantize_level=16.0,
                                     quantize_method=1, dither_seed=7),
        "gzip1_i16.fits": dict(data=wide.astype(np.int16), compression_type="GZIP_1",
                               tile_size=(16, 8)),
        "gzip2_f32.fits": dict(data=wide.astype(np.float32), compression_type="GZIP_2",
                               tile_size=(30, 10), quantize_level=0.0),
        "hcompress_i16.fits": dict(data=spot_frame(32, 32, seed=4).astype(np.int16),
                                   compression_type="HCOMPRESS_1", tile_size=(16, 16)),
        "plio_i16.fits": dict(data=(wide > 1010).astype(np.int16), compression_type="PLIO_1"),
    }
    for name, args in compressed.items():
        data = args.pop("data")
        hdu = fits.CompImageHDU(data, header=header_keys(), **args)
        write(name, to_bytes(fits.HDUList([fits.PrimaryHDU(), hdu])))

    # Other structures the reader refuses or skips.
    write("cube.fits", to_bytes(fits.HDUList([fits.PrimaryHDU(np.zeros((2, 4, 4), np.int16))])))
    write("spectrum.fits", to_bytes(fits.HDUList([fits.PrimaryHDU(np.arange(40, dtype=np.int16))])))
    table = fits.BinTableHDU.from_columns([fits.Column(name="FLUX", format="1D", array=[1.0, 2.0])])
    write("table_only.fits", to_bytes(fits.HDUList([fits.PrimaryHDU(), table])))

    # Broken copies: cut in the header, cut in the data, cut in a compressed heap; a
    # tile-compressed image whose ZTILE1 is 0 (CFITSIO divided by it: SIGFPE).
    f64 = open(os.path.join(OUT, "plain_f64.fits"), "rb").read()
    write("cut_header.fits", f64[:1000])
    write("cut_data.fits", f64[:2880 + 1500])
    rice = open(os.path.join(OUT, "rice_i16.fits"), "rb").read()
    write("cut_rice_heap.fits", rice[:len(rice) - 2880 + 200])
    ztile = rice.replace(b"ZTILE1  =                   16", b"ZTILE1  =                    0")
    assert ztile != rice
    write("rice_ztile1_zero.fits", ztile)
    # What the first campaign found (tests/unit/fits_io_test.cc has each as a regression test):
    # an END card CFITSIO reads as END and the screen did not ("END   TFORM1..."), hiding
    # ZTILE1 = 0; and a NAXIS1 CFITSIO cannot parse in a header the file cuts short (a
    # calloc sized from an unset variable).
    end_at = rice.index(b"END" + b" " * 77, 2880)
    hidden = bytearray(ztile)
    hidden[end_at:end_at + 80] = b"END   TFORM1  = '1PB(43) '".ljust(80)
    write("end_card_variant.fits", bytes(hidden))
    cut = bytearray(rice[:2 * 2880])
    cut[end_at:end_at + 80] = b" " * 80
    naxis1_at = rice.index(b"NAXIS1  =", 2880)
    cut[naxis1_at:naxis1_at + 80] = b"NAXIS1  =                   :/// width".ljust(80)
    write("naxis1_unreadable_cut.fits", bytes(cut))

    total = sum(os.path.getsize(os.path.join(OUT, f)) for f in os.listdir(OUT))
    print("wrote %d files, %d bytes, to %s" % (len(os.listdir(OUT)), total, OUT))
    if total >= 300 * 1024:
        sys.exit("the corpus must stay under 300 KB")


if __name__ == "__main__":
    main()
