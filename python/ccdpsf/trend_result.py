"""read_trend: one `ccdpsf trend` output folder (trend.json, its CSV tables, groups/)."""

import collections.abc
import math
from pathlib import Path

import numpy as np
from astropy.io import ascii as astropy_ascii
from astropy.table import MaskedColumn, QTable
import astropy.units as u

from .errors import OutputFormatError, OutputMissingError
from .fit_result import read_fit, read_json
from .units import unit_from_name

# Today's relation CSVs name their columns generically; the quantity is in the file's name
# (fwhm_um_vs_wavelength.csv) and the abscissa's quantity in trend.json
# (relations[name]["abscissa"], e.g. "wavelength_nm" or "intensity_e").
_GENERIC_VALUE_COLUMNS = ("median", "lo68", "hi68", "lo95", "hi95", "sd", "upper_limit_95")

# Requirement rows: numbers in the unit of what they constrain.
_REQUIREMENT_VALUE_KEYS = ("value", "lo68", "hi68", "lo95", "hi95", "sd", "limit", "margin")


def read_trend(folder):
    """Read a `ccdpsf trend` output folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise OutputMissingError(f"{folder}: no such folder")
    return TrendResult(folder)


class TrendResult:
    """A campaign's outputs.

    summary: trend.json as a dict. tables: every CSV of the folder, file stem -> QTable with
    units. relations: the relation tables (stem -> QTable: one row per setting). groups_table:
    groups.csv. requirements, focus_series_requirements: QTables (a CSV of that name when the
    folder has one, else built from trend.json). groups: group name -> FitResult, each read
    on first access.
    """

    def __init__(self, folder):
        self.folder = Path(folder)
        self.summary = read_json(self.folder / "trend.json", "ccdpsf trend")
        relations = self.summary.get("relations") or {}
        self.tables = {}
        for path in sorted(self.folder.glob("*.csv")):
            self.tables[path.stem] = read_csv(path, relations.get(path.stem))
        self.groups = GroupFits(self.folder, self.summary.get("groups") or [])

    def __repr__(self):
        return (f"<ccdpsf trend {str(self.folder)!r}: {len(self.groups)} groups, "
                f"{len(self.relations)} relation tables>")

    @property
    def relations(self):
        names = set(self.summary.get("relations") or {})
        return {stem: t for stem, t in self.tables.items() if stem in names or "_vs_" in stem}

    @property
    def groups_table(self):
        if "groups" not in self.tables:
            raise OutputMissingError(f"{self.folder}: no groups.csv")
        return self.tables["groups"]

    @property
    def requirements(self):
        if "requirements" in self.tables:
            return self.tables["requirements"]
        return requirements_table(self.summary.get("requirements") or [])

    @property
    def focus_series_requirements(self):
        if "focus_series_requirements" in self.tables:
            return self.tables["focus_series_requirements"]
        return requirements_table(self.summary.get("focus_series_requirements") or [])


class GroupFits(collections.abc.Mapping):
    """Group name -> FitResult of groups/NAME, read when first asked for. Groups that failed
    (no fit folder) are not keys; their reasons are in ``failures``."""

    def __init__(self, folder, groups_json):
        self._folders = {}
        self.failures = {}
        for g in groups_json:
            name = g.get("name")
            report = g.get("report")
            if report:
                self._folders[name] = folder / report
            elif name is not None:
                self.failures[name] = g.get("failure")
        # Group folders trend.json does not list (an older trend.json): every groups/NAME
        # with a fit.json.
        groups_dir = folder / "groups"
        if groups_dir.is_dir():
            for path in sorted(groups_dir.iterdir()):
                if (path / "fit.json").is_file() and path.name not in self._folders:
                    self._folders[path.name] = path
        self._fits = {}

    def __getitem__(self, name):
        if name not in self._folders:
            reason = self.failures.get(name)
            if name in self.failures:
                raise KeyError(f"group {name!r} has no fit: {reason}")
            raise KeyError(f"no group {name!r}; groups: {sorted(self._folders)}")
        if name not in self._fits:
            self._fits[name] = read_fit(self._folders[name])
        return self._fits[name]

    def __iter__(self):
        return iter(self._folders)

    def __len__(self):
        return len(self._folders)

    def folder(self, name):
        return self._folders[name]


def read_csv(path, relation_json=None):
    """One ccdpsf CSV as a QTable: numeric columns as Quantities in the unit their names
    announce (missing cells NaN), text columns as strings (missing cells '').

    ``relation_json``: the relation's trend.json entry, for today's generic columns
    (abscissa, median, ...), whose units come from the relation's name and its abscissa."""
    try:
        raw = astropy_ascii.read(str(path), format="csv", guess=False)
    except Exception as error:  # astropy raises several kinds for a malformed file
        raise OutputFormatError(f"{path}: not a readable CSV table ({error})") from error
    generic_units = _generic_units(Path(path).stem, relation_json)
    table = QTable()
    for name in raw.colnames:
        column = raw[name]
        masked = np.asarray(column.mask) if isinstance(column, MaskedColumn) else np.zeros(
            len(column), bool)
        unit = generic_units.get(name, unit_from_name(name))
        announces_number = name in generic_units or unit != u.dimensionless_unscaled
        if len(column) and masked.all():
            # Every cell empty (no upper limits, no failures): astropy cannot tell the type.
            table[name] = (np.full(len(column), np.nan) * unit if announces_number
                           else np.full(len(column), "", dtype=str))
        elif column.dtype.kind in "iu" and not masked.any() and not announces_number:
            table[name] = np.asarray(column)  # counts and 0/1 flags stay integers
        elif column.dtype.kind in "iuf":
            values = np.asarray(column, dtype=np.float64)
            values[masked] = np.nan
            table[name] = values * unit
        else:
            text = column.filled("") if isinstance(column, MaskedColumn) else column
            table[name] = np.asarray(text, dtype=str)
    return table


def _generic_units(stem, relation_json):
    """Units of today's generic relation columns, from the file's name and trend.json."""
    if "_vs_" not in stem:
        return {}
    quantity = stem.split("_vs_")[0]
    units = {name: unit_from_name(quantity) for name in _GENERIC_VALUE_COLUMNS}
    abscissa = (relation_json or {}).get("abscissa")
    if not abscissa:
        abscissa = {"wavelength": "wavelength_nm", "intensity": "intensity_e"}.get(
            stem.split("_vs_")[-1], "")
    units["abscissa"] = unit_from_name(abscissa)
    return units


def requirements_table(rows):
    """trend.json's requirement entries as a QTable, one row per requirement.

    A requirement constrains a metric (fwhm_um, ellipticity, ...) or a relation's coefficient
    (alpha), each with its own unit, so value / lo68 / hi68 / sd / limit / margin are plain
    numbers in the row's ``unit`` (a string column)."""
    table = QTable()
    if not rows:
        return table
    keys = []
    for row in rows:
        for key in row:
            if key not in keys and key not in ("notes", "at"):
                keys.append(key)
    for key in keys:
        values = [row.get(key) for row in rows]
        if key in _REQUIREMENT_VALUE_KEYS or key == "pass_probability":
            table[key] = np.array([math.nan if v is None else float(v) for v in values])
        elif all(isinstance(v, bool) or v is None for v in values):
            table[key] = np.array([bool(v) for v in values])
        else:
            table[key] = np.array(["" if v is None else str(v) for v in values], dtype=str)
    table["unit"] = np.array([_requirement_unit(row) for row in rows], dtype=str)
    for at_key in sorted({k for row in rows for k in (row.get("at") or {})}):
        unit = unit_from_name(at_key)
        table["at_" + at_key] = np.array(
            [math.nan if (row.get("at") or {}).get(at_key) is None else row["at"][at_key]
             for row in rows]) * unit
    table["notes"] = np.array(["; ".join(row.get("notes") or []) for row in rows], dtype=str)
    return table


def _requirement_unit(row):
    if row.get("metric"):
        return unit_from_name(row["metric"]).to_string()
    # A coefficient: alpha (a power law's exponent) is dimensionless; a linear relation's
    # slope is the quantity's unit per the abscissa's, which trend.json does not give here.
    return "" if row.get("coefficient") in ("alpha", None) else "see relation"
