"""read_fit: one `ccdpsf fit` output folder (fit.json, chain.fits, residuals.fits)."""

import collections
import json
import numbers
from pathlib import Path

import numpy as np
from astropy.table import QTable

from .chain_file import ChainFile
from .errors import NoChainError, OutputFormatError, OutputMissingError
from .residuals import Residuals
from .units import fits_valid_name

Covariance = collections.namedtuple("Covariance", ["names", "matrix"])
Covariance.__doc__ = ("The Laplace covariance of the identified parameters: names (list) and "
                      "matrix (numpy array, len(names) x len(names), in the parameters' units "
                      "squared).")


def read_json(path, what):
    """A JSON output file as Python objects, with the reader's errors for a missing or
    malformed file."""
    path = Path(path)
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError as error:
        raise OutputMissingError(f"{path.parent}: no {path.name}; is this a {what} output "
                                 f"folder?") from error
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise OutputFormatError(f"{path}: not valid JSON ({error})") from error


def fit_subfolders(folder):
    """Subfolders holding a fit.json: `ccdpsf fit` of several files without --joint."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if (p / "fit.json").is_file())


def read_fit(folder):
    """Read a `ccdpsf fit` output folder (or one of trend's groups/NAME folders)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise OutputMissingError(f"{folder}: no such folder")
    if not (folder / "fit.json").is_file():
        subfolders = fit_subfolders(folder)
        if subfolders:
            names = ", ".join(p.name for p in subfolders[:5])
            raise OutputMissingError(
                f"{folder} holds one fit per file in subfolders ({names}"
                f"{', ...' if len(subfolders) > 5 else ''}): read each with "
                f"read_fit('{subfolders[0]}')")
    return FitResult(folder)


class FitResult:
    """A fit's outputs. The chain is read on first use.

    summary: fit.json as a dict. names: the fitted parameters in the model's (and the chain's)
    order, as fit.json names them (``x_px.0``). derived_names: the derived quantities stored
    per draw in the chain (none in older chain files).
    """

    def __init__(self, folder):
        self.folder = Path(folder)
        self.summary = read_json(self.folder / "fit.json", "ccdpsf fit")
        self._chain = None
        self._residuals = None
        parameters = self.summary.get("parameters")
        if not isinstance(parameters, dict):
            raise OutputFormatError(f"{self.folder / 'fit.json'}: no \"parameters\" object")
        # fit.json's objects are sorted by name; map_vs_mcmc lists the parameters in the
        # model's order, then the derived quantities.
        order = [row.get("name") for row in self.summary.get("map_vs_mcmc", [])]
        in_order = [n for n in order if n in parameters]
        self._summary_names = in_order if len(in_order) == len(parameters) else list(parameters)
        known = list(parameters) + list(self.summary.get("derived", {}) or {})
        self._internal_name = {}
        for name in known:
            self._internal_name[fits_valid_name(name)] = name
            self._internal_name[name] = name

    def __repr__(self):
        verdict = (self.summary.get("quality") or {}).get("verdict")
        return f"<ccdpsf fit {str(self.folder)!r}: {len(self.names)} parameters, verdict {verdict}>"

    # --- the chain -------------------------------------------------------------------------

    @property
    def has_chain(self):
        return (self.folder / "chain.fits").is_file()

    def _chain_file(self):
        if self._chain is None:
            path = self.folder / "chain.fits"
            if not path.is_file():
                raise NoChainError(
                    f"{self.folder}: no chain.fits: this fit ran without MCMC (--nomcmc); "
                    "fit.json has the MAP and Laplace widths only")
            self._chain = ChainFile(path)
        return self._chain

    @property
    def names(self):
        if self.has_chain:
            return [self._internal(c) for c in self._chain_file().parameter_columns]
        return list(self._summary_names)

    @property
    def derived_names(self):
        return [self._internal(c) for c in self._chain_file().derived_columns]

    @property
    def column_names(self):
        """The chain's parameter and derived columns as written in chain.fits."""
        chain = self._chain_file()
        return chain.parameter_columns + chain.derived_columns

    @property
    def units(self):
        """name -> astropy unit of every parameter and derived quantity in the chain."""
        chain = self._chain_file()
        return {self._internal(c): chain.units[c] for c in self.column_names}

    @property
    def burn_in(self):
        return self._chain_file().burn_in

    @property
    def walkers(self):
        return self._chain_file().walkers

    @property
    def steps(self):
        """Steps stored, burn-in included."""
        return self._chain_file().steps

    @property
    def converged(self):
        return self._chain_file().converged

    def _internal(self, column):
        return self._internal_name.get(column, column)

    def _slice(self, array, discard, thin, flat):
        discard = self.burn_in if discard is None else discard
        if not isinstance(discard, numbers.Integral) or discard < 0:
            raise ValueError(f"discard = {discard!r}: a number of steps >= 0 (or None for BURNIN)")
        if not isinstance(thin, numbers.Integral) or thin < 1:
            raise ValueError(f"thin = {thin!r}: an integer >= 1")
        # emcee's convention: the first step kept is discard + thin - 1.
        out = np.array(array[discard + thin - 1::thin])
        return out.reshape((-1,) + out.shape[2:]) if flat else out

    def get_chain(self, discard=None, flat=False, thin=1):
        """Parameter draws, shape (steps, walkers, parameters) as emcee's get_chain: the first
        ``discard`` steps dropped (None: the file's BURNIN), every ``thin``-th step kept,
        ``flat=True`` -> (steps x walkers, parameters), step-major. Raises NoChainError for a
        --nomcmc fit."""
        chain = self._chain_file()
        return self._slice(chain.values[:, :, :len(chain.parameter_columns)], discard, thin, flat)

    def get_derived(self, discard=None, flat=False, thin=1):
        """Derived quantities per draw (shape as get_chain's, in derived_names' order)."""
        chain = self._chain_file()
        return self._slice(chain.values[:, :, len(chain.parameter_columns):], discard, thin, flat)

    def get_log_prob(self, discard=None, flat=False, thin=1):
        """Log posterior per draw, shape (steps, walkers) (flat: steps x walkers)."""
        return self._slice(self._chain_file().log_prob, discard, thin, flat)

    @property
    def log_prob(self):
        return self.get_log_prob()

    @property
    def table(self):
        """The post-burn-in draws as an astropy QTable: walker, step, log_prob, the parameters
        and the derived quantities with their units, one row per draw, step-major."""
        chain = self._chain_file()
        kept = chain.values[chain.burn_in:]
        steps = kept.shape[0]
        table = QTable()
        table["walker"] = np.tile(np.arange(chain.walkers), steps)
        table["step"] = np.repeat(np.arange(chain.burn_in, chain.steps), chain.walkers)
        table["log_prob"] = chain.log_prob[chain.burn_in:].reshape(-1)
        for i, column in enumerate(chain.parameter_columns + chain.derived_columns):
            table[self._internal(column)] = kept[:, :, i].reshape(-1) * chain.units[column]
        table.meta["BURNIN"] = chain.burn_in
        table.meta["WALKERS"] = chain.walkers
        table.meta["NSTEPS"] = chain.steps
        return table

    def to_arviz_dict(self, discard=None, thin=1):
        """A dict for ``arviz.from_dict(**d)``: posterior name -> array (walkers, steps) (each
        walker an ArviZ chain), derived quantities included; sample_stats lp likewise."""
        posterior = {}
        chain = self.get_chain(discard=discard, thin=thin)
        for i, name in enumerate(self.names):
            posterior[name] = np.ascontiguousarray(chain[:, :, i].T)
        derived = self.get_derived(discard=discard, thin=thin)
        for i, name in enumerate(self.derived_names):
            posterior[name] = np.ascontiguousarray(derived[:, :, i].T)
        lp = np.ascontiguousarray(self.get_log_prob(discard=discard, thin=thin).T)
        return {"posterior": posterior, "sample_stats": {"lp": lp}}

    # --- the rest of the folder ------------------------------------------------------------

    @property
    def covariance(self):
        """fit.json's Laplace covariance (Covariance(names, matrix)), None when absent."""
        cov = self.summary.get("covariance")
        if not cov:
            return None
        try:
            names = list(cov["names"])
            matrix = np.array([[np.nan if v is None else v for v in row] for row in cov["matrix"]],
                              dtype=np.float64)
        except (KeyError, TypeError, ValueError) as error:
            raise OutputFormatError(f"{self.folder / 'fit.json'}: \"covariance\" is not "
                                    f"{{names, matrix}} ({error})") from error
        if matrix.shape != (len(names), len(names)):
            raise OutputFormatError(f"{self.folder / 'fit.json'}: covariance matrix is "
                                    f"{matrix.shape}, for {len(names)} names")
        return Covariance(names, matrix)

    @property
    def residuals(self):
        if self._residuals is None:
            self._residuals = Residuals(self.folder / "residuals.fits")
        return self._residuals

    @property
    def verdict(self):
        return (self.summary.get("quality") or {}).get("verdict")
