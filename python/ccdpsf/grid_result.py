"""read_grid: one `ccdpsf grid` output folder (psf_map, catalogue, segments, relations)."""

from pathlib import Path

from astropy.table import QTable

from .errors import OutputMissingError
from .fit_result import read_json


def read_grid(folder):
    """Read a `ccdpsf grid` output folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise OutputMissingError(f"{folder}: no such folder")
    return GridResult(folder)


def _read_table(path):
    # The FITS tables carry TUNITn, so the columns come back as Quantities (um, pix, nm).
    if not path.is_file():
        raise OutputMissingError(f"{path}: missing (not a `ccdpsf grid` folder?)")
    return QTable.read(path, format="fits")


class GridResult:
    """A grid's outputs.

    psf_map: one row per spot (position, segment, metrics with _lo68/_hi68 bounds, verdict,
    reason), a QTable with units. ok: the rows with verdict 'ok'. catalogue: every source of
    every frame. relations: each spot's relations across settings (None for one setting).
    segments: per setting and segment medians (None when absent). run: run.json as a dict.
    interval: what the _lo68 / _hi68 bounds are (posterior or Laplace).
    """

    def __init__(self, folder):
        self.folder = Path(folder)
        self.run = read_json(self.folder / "run.json", "ccdpsf grid")
        self.psf_map = _read_table(self.folder / "psf_map.fits")
        self.interval = self.psf_map.meta.get("INTERVAL", "")
        self.catalogue = _read_table(self.folder / "catalogue.fits")
        relations = self.folder / "spot_relations.fits"
        self.relations = _read_table(relations) if relations.is_file() else None
        segments = self.folder / "segments.csv"
        self.segments = QTable.read(segments, format="ascii.csv") if segments.is_file() else None

    @property
    def ok(self):
        return self.psf_map[self.psf_map["verdict"] == "ok"]

    def __repr__(self):
        return (f"<ccdpsf grid {str(self.folder)!r}: {len(self.psf_map)} spots, "
                f"{len(self.ok)} ok>")
