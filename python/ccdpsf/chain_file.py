"""Reading a fit's chain.fits, in the current layout and the older one.

Current layout (the shared output plan): HDU 'CHAIN' is a binary table with columns walker,
step, log_prob, then NPARAM fitted parameters, then NDERIVED derived quantities per draw, each
with its TUNIT; the keywords BURNIN, WALKERS, NSTEPS, NPARAM, NDERIVED, CONVERGD are in the
CHAIN header. Older files have no NPARAM: every column after log_prob is a parameter, the
keywords (BURNIN, WALKERS, CONVERGD) are in the primary header, the names keep their dots
(``x_px.0``) and the columns carry no units. A column without TUNIT gets the unit its name
announces (``x_px_0`` -> pix; units.py).

Rows may come in any order: each row is placed by its own (step, walker), and every cell of the
steps x walkers grid must be filled exactly once.
"""

import numpy as np
from astropy.io import fits

from .errors import OutputFormatError
from .units import unit_from_fits, unit_from_name

_LEADING_COLUMNS = ("walker", "step", "log_prob")


class ChainFile:
    """The whole stored chain (burn-in included) of one chain.fits.

    Attributes:
      path: the file.
      new_format: True when the CHAIN header has NPARAM (the shared plan's layout).
      parameter_columns, derived_columns: column names as written in the file.
      units: column name -> astropy unit.
      walkers, steps, burn_in: the ensemble's size, the stored steps, the steps to discard.
      converged: the CONVERGD keyword (None when absent).
      values: float array (steps, walkers, parameters + derived), parameters first.
      log_prob: float array (steps, walkers).
    """

    def __init__(self, path):
        self.path = str(path)
        try:
            hdul = fits.open(self.path, memmap=False)
        except OSError as error:
            raise OutputFormatError(f"{self.path}: not a readable FITS file ({error})") from error
        with hdul:
            table_hdu = _chain_hdu(hdul, self.path)
            header, primary = table_hdu.header, hdul[0].header
            names = list(table_hdu.columns.names)
            if [n.lower() for n in names[:3]] != list(_LEADING_COLUMNS):
                raise OutputFormatError(
                    f"{self.path}: the chain's first columns are {names[:3]}, "
                    f"expected {list(_LEADING_COLUMNS)}")
            value_names = names[3:]
            self.new_format = "NPARAM" in header
            if self.new_format:
                num_param = _int_keyword(header, "NPARAM", self.path)
                num_derived = (_int_keyword(header, "NDERIVED", self.path)
                               if "NDERIVED" in header else len(value_names) - num_param)
                if num_param < 0 or num_derived < 0 or num_param + num_derived != len(value_names):
                    raise OutputFormatError(
                        f"{self.path}: NPARAM = {num_param} and NDERIVED = {num_derived} do not "
                        f"account for the {len(value_names)} columns after log_prob")
            else:
                num_param, num_derived = len(value_names), 0
            self.parameter_columns = value_names[:num_param]
            self.derived_columns = value_names[num_param:]
            # TUNIT when the column has one; else the unit its name announces (older files
            # have no TUNIT at all; a dimensionless quantity's name announces none).
            self.units = {
                c.name: (_column_unit(c, self.path) if c.unit is not None and str(c.unit).strip()
                         else unit_from_name(c.name, indexed=True))
                for c in table_hdu.columns[3:]
            }

            def keyword(name):
                # Current files: the CHAIN header; older ones: the primary header.
                if name in header:
                    return header[name]
                return primary.get(name)

            data = table_hdu.data
            rows = 0 if data is None else len(data)
            walker = np.asarray(data[names[0]], dtype=np.int64) if rows else np.zeros(0, np.int64)
            step = np.asarray(data[names[1]], dtype=np.int64) if rows else np.zeros(0, np.int64)
            self.walkers = _size(keyword("WALKERS"), walker, "WALKERS", self.path)
            self.steps = _size(keyword("NSTEPS"), step, "NSTEPS", self.path)
            burn_in = keyword("BURNIN")
            if burn_in is None:
                raise OutputFormatError(f"{self.path}: no BURNIN keyword (steps to discard)")
            self.burn_in = int(burn_in)
            if not 0 <= self.burn_in <= self.steps:
                raise OutputFormatError(
                    f"{self.path}: BURNIN = {self.burn_in} is outside 0 to the {self.steps} steps")
            converged = keyword("CONVERGD")
            self.converged = None if converged is None else bool(converged)

            if rows != self.walkers * self.steps:
                raise OutputFormatError(
                    f"{self.path}: {rows} rows, but {self.walkers} walkers x {self.steps} steps "
                    f"= {self.walkers * self.steps}")
            if rows and (walker.min() < 0 or walker.max() >= self.walkers or step.min() < 0
                         or step.max() >= self.steps):
                raise OutputFormatError(
                    f"{self.path}: a walker or step index outside 0..{self.walkers - 1} / "
                    f"0..{self.steps - 1}")
            cell = step * self.walkers + walker
            if np.unique(cell).size != rows:
                raise OutputFormatError(f"{self.path}: a (step, walker) pair appears twice")
            self.values = np.empty((self.steps, self.walkers, len(value_names)))
            for i, name in enumerate(value_names):
                self.values[step, walker, i] = np.asarray(data[name], dtype=np.float64)
            self.log_prob = np.empty((self.steps, self.walkers))
            self.log_prob[step, walker] = np.asarray(data[names[2]], dtype=np.float64)


def _chain_hdu(hdul, path):
    for hdu in hdul[1:]:
        if isinstance(hdu, fits.BinTableHDU) and hdu.name.upper() == "CHAIN":
            return hdu
    if len(hdul) > 1 and isinstance(hdul[1], fits.BinTableHDU):
        return hdul[1]
    raise OutputFormatError(f"{path}: no binary table with EXTNAME 'CHAIN'")


def _int_keyword(header, name, path):
    value = header[name]
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise OutputFormatError(f"{path}: keyword {name} = {value!r} is not an integer")
    return int(value)


def _size(keyword_value, indices, name, path):
    """A grid dimension: the keyword when present, else one more than the largest index."""
    if keyword_value is not None:
        value = int(keyword_value)
        if value < 0:
            raise OutputFormatError(f"{path}: {name} = {value} is negative")
        return value
    return int(indices.max()) + 1 if indices.size else 0


def _column_unit(column, path):
    try:
        return unit_from_fits(column.unit)
    except ValueError as error:
        raise OutputFormatError(
            f"{path}: column {column.name} has TUNIT {column.unit!r}, not a unit ({error})"
        ) from error
