"""Units of ccdpsf quantities from the suffix of their names.

ccdpsf names every quantity with its unit as the last part of the name (``fwhm_um``,
``peak_e``, ``wavelength_nm``); no suffix means dimensionless. The shared output plan fixes the
suffixes of the trend CSVs; the fit's parameter and derived names use a few more
(``r2_px2``, ``r2_arcsec2``, ``defocus_rate_px_per_um``), listed here too so that chains
written before columns carried TUNIT still get units.
"""

import re

import astropy.units as u

# Longest suffix first, so that "_e_per_adu" wins over "_adu" and "_px_per_um" over "_um".
_SUFFIX_UNITS = sorted(
    {
        "_nm": u.nm,
        "_um": u.um,
        "_um2": u.um**2,
        "_px": u.pix,
        "_px2": u.pix**2,
        "_arcsec2": u.arcsec**2,
        "_px_per_um": u.pix / u.um,
        "_e": u.electron,
        "_s": u.s,
        "_adu": u.adu,
        "_e_per_adu": u.electron / u.adu,
        "_px_per_e": u.pix / u.electron,
        "_per_e": 1 / u.electron,
    }.items(),
    key=lambda item: -len(item[0]),
)

# Statistic suffixes that follow a quantity's name in tables (``fwhm_um_lo68``): the column
# has the quantity's unit.
_STATISTIC_SUFFIX = re.compile(
    r"_(median|map|mean|sd|laplace_sd|lo68|hi68|lo95|hi95|lo997|hi997|upper_limit_95)$"
)

# Per-exposure parameters carry the exposure's index after the unit: "x_px.3" (internal) or
# "x_px_3" (FITS-valid); "flux_ratio.2" is dimensionless.
_INDEX_SUFFIX = re.compile(r"[._]\d+$")


def _unit_of_stem(name):
    for suffix, unit in _SUFFIX_UNITS:
        if name.endswith(suffix) and len(name) > len(suffix):
            return unit
    return None


def unit_from_name(name, indexed=False):
    """The astropy unit a ccdpsf quantity's name announces; dimensionless when none.

    ``indexed=True`` also accepts a trailing exposure index (fit parameters such as
    ``x_px.0``); tables never have one, and there ``peak_e_3`` would be misread.
    """
    for candidate in _candidates(name, indexed):
        unit = _unit_of_stem(candidate)
        if unit is not None:
            return unit
    return u.dimensionless_unscaled


def _candidates(name, indexed):
    yield name
    stripped = _STATISTIC_SUFFIX.sub("", name)
    if stripped != name:
        yield stripped
    if indexed:
        unindexed = _INDEX_SUFFIX.sub("", name)
        if unindexed != name:
            yield unindexed


def unit_from_fits(tunit):
    """The astropy unit of a FITS TUNIT string ('' or None: dimensionless).

    ccdpsf writes 'pix', 'um', 'um2', 'electron', 'nm', 's': astropy's generic parser reads
    them all ('electron' is not in its strict FITS list). Raises ValueError for a string
    neither parser knows.
    """
    if tunit is None or not str(tunit).strip():
        return u.dimensionless_unscaled
    text = str(tunit).strip()
    try:
        return u.Unit(text)
    except ValueError:
        return u.Unit(text, format="fits")


def fits_valid_name(name):
    """A column name as the shared plan writes it to FITS: every character outside
    [A-Za-z0-9_] becomes '_' (``x_px.0`` -> ``x_px_0``)."""
    return re.sub(r"[^A-Za-z0-9_]", "_", name)
