"""A fit's residuals.fits: per exposure k the stamps DATA_k, MODEL_k, RESID_k (electrons) and
NRESID_k ((data - model) / sigma), masked pixels NaN, as numpy arrays indexed [y, x]."""

import urllib.parse

import numpy as np
from astropy.io import fits

from .errors import OutputFormatError, OutputMissingError

KINDS = ("DATA", "MODEL", "RESID", "NRESID")


class Residuals:
    """Read on first use; ``residuals.data(k)``, ``.model(k)``, ``.resid(k)``, ``.nresid(k)``,
    ``residuals["MODEL_2"]``, ``len(residuals)`` (exposures), ``residuals.exposures`` (index,
    source file, stamp origin in frame pixels), ``residuals.header("DATA_0")``."""

    def __init__(self, path):
        self.path = str(path)
        self._images = None
        self._headers = None

    def _load(self):
        if self._images is not None:
            return
        try:
            hdul = fits.open(self.path, memmap=False)
        except FileNotFoundError as error:
            raise OutputMissingError(f"{self.path}: no residuals.fits in this fit folder") from error
        except OSError as error:
            raise OutputFormatError(f"{self.path}: not a readable FITS file ({error})") from error
        images, headers = {}, {}
        with hdul:
            for hdu in hdul[1:]:
                if hdu.data is None:
                    continue
                images[hdu.name.upper()] = np.array(hdu.data, dtype=np.float64)
                headers[hdu.name.upper()] = hdu.header.copy()
        self._images, self._headers = images, headers

    def __len__(self):
        self._load()
        return sum(1 for name in self._images if name.startswith("DATA_"))

    def __getitem__(self, extname):
        self._load()
        key = str(extname).upper()
        if key not in self._images:
            raise KeyError(f"{self.path} has no HDU {extname!r}; it has {sorted(self._images)}")
        return self._images[key]

    def keys(self):
        self._load()
        return list(self._images)

    def header(self, extname):
        self[extname]  # the same error for a missing HDU
        return self._headers[str(extname).upper()]

    def data(self, k):
        """Exposure k's bias-subtracted stamp [electrons], masked pixels NaN."""
        return self[f"DATA_{int(k)}"]

    def model(self, k):
        """Exposure k's MAP model [electrons]."""
        return self[f"MODEL_{int(k)}"]

    def resid(self, k):
        """Exposure k's data - model [electrons]."""
        return self[f"RESID_{int(k)}"]

    def nresid(self, k):
        """Exposure k's (data - model) / sigma (dimensionless)."""
        return self[f"NRESID_{int(k)}"]

    @property
    def exposures(self):
        """One dict per exposure: index, source (the input file, percent-decoded), origin_px
        (x, y) of the stamp's pixel [0, 0] in the frame (LTV1/LTV2 negated)."""
        out = []
        for k in range(len(self)):
            h = self.header(f"DATA_{k}")
            source = h.get("SOURCE")
            out.append({
                "index": k,
                "source": None if source is None else urllib.parse.unquote(
                    source, errors="surrogateescape"),
                "origin_px": (-float(h.get("LTV1", 0.0)), -float(h.get("LTV2", 0.0))),
            })
        return out
