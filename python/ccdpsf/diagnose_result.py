"""read_diagnose: one `ccdpsf diagnose` output folder (diagnose.json).

diagnose fits the baseline model, tests every catalogue effect against its residuals, adopts
the best one if it passes the decision rule, and repeats: each repetition is a round."""

import math
from pathlib import Path

import numpy as np
from astropy.table import Table

from .errors import OutputFormatError, OutputMissingError
from .fit_result import read_json


def read_diagnose(folder):
    """Read a `ccdpsf diagnose` output folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise OutputMissingError(f"{folder}: no such folder")
    return Diagnosis(folder)


class Diagnosis:
    """summary: diagnose.json as a dict; rounds: list of Round; verdict, named_effects,
    final_fit and attributions as diagnose.json has them."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.summary = read_json(self.folder / "diagnose.json", "ccdpsf diagnose")
        rounds = self.summary.get("rounds")
        if not isinstance(rounds, list):
            raise OutputFormatError(f"{self.folder / 'diagnose.json'}: no \"rounds\" list")
        self.rounds = [Round(i, r) for i, r in enumerate(rounds)]

    def __repr__(self):
        return (f"<ccdpsf diagnose {str(self.folder)!r}: {len(self.rounds)} rounds, named "
                f"{self.named_effects}>")

    @property
    def verdict(self):
        return self.summary.get("verdict")

    @property
    def named_effects(self):
        return list(self.summary.get("named_effects") or [])

    @property
    def final_fit(self):
        return self.summary.get("final_fit")

    @property
    def attributions(self):
        return list(self.summary.get("attributions") or [])


class Round:
    """One round: the model fitted (description, effects), its fit (chi2, dof, parameters),
    the residual statistics and the candidates tested against them, what was adopted.

    raw: the round's JSON object; every attribute below is read from it.
    """

    def __init__(self, index, raw):
        if not isinstance(raw, dict):
            raise OutputFormatError(f"diagnose.json: round {index} is not an object")
        self.index = index
        self.raw = raw
        model = raw.get("model") or {}
        self.model_description = model.get("description")
        self.effects = list(model.get("effects") or [])
        self.fit = raw.get("fit") or {}
        self.chi2_per_dof = raw.get("chi2_per_dof")
        self.candidates = list(raw.get("candidates") or [])
        self.adopted = raw.get("adopted")
        self.rivals = list(raw.get("rivals") or [])
        self.verdict = raw.get("verdict")
        self.tested = raw.get("tested")
        self.num_tested = raw.get("num_tested")
        self.p_threshold = raw.get("p_threshold")
        self.intensity_classes = list(raw.get("intensity_classes") or [])
        profile = raw.get("radial_profile") or {}
        # Mean normalised residual in 1-px annuli (inner radius [px]) and pixels per annulus.
        self.radial_profile = {key: _numbers(values) for key, values in profile.items()}

    def __repr__(self):
        return (f"<round {self.index}: {self.model_description}, chi2/dof {self.chi2_per_dof}, "
                f"adopted {self.adopted}>")

    @property
    def parameters(self):
        """The round's fitted parameters: name -> {map, laplace_sd, at_bound}."""
        return self.fit.get("parameters") or {}

    @property
    def statistics(self):
        """The residual statistics (chi2_per_dof, core_z, ring_z, ...) as a Table: name,
        value, p_value, predictive_mean, predictive_sd, tail, p_method, description."""
        return _table(self.raw.get("statistics") or [],
                      ["name", "value", "p_value", "predictive_mean", "predictive_sd", "tail",
                       "p_method", "description"])

    @property
    def candidates_table(self):
        """Every candidate effect as a Table: name, kind, status, and for tested ones
        delta_loglike, lr, p_value, delta_bic, log_bayes_factor, significant, num_parameters,
        chi2_per_dof_with (NaN / '' / False where a candidate was not tested)."""
        return _table(self.candidates,
                      ["name", "kind", "status", "delta_loglike", "lr", "p_value", "delta_bic",
                       "log_bayes_factor", "significant", "nested", "num_parameters",
                       "chi2_per_dof_with", "reason"])


def _numbers(values):
    if isinstance(values, list):
        return np.array([math.nan if v is None else v for v in values], dtype=np.float64)
    return values


_NUMBER_KEYS = {"value", "p_value", "predictive_mean", "predictive_sd", "delta_loglike", "lr",
                "delta_bic", "log_bayes_factor", "chi2_per_dof_with", "num_parameters"}
_BOOL_KEYS = {"significant", "nested"}


def _table(rows, keys):
    table = Table()
    for key in keys:
        values = [row.get(key) for row in rows]
        if key in _NUMBER_KEYS:
            table[key] = np.array([math.nan if v is None else float(v) for v in values],
                                  dtype=np.float64)
        elif key in _BOOL_KEYS:
            table[key] = np.array([bool(v) for v in values], dtype=bool)
        else:
            table[key] = np.array(["" if v is None else str(v) for v in values], dtype=str)
    return table
