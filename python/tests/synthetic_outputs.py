"""Writers of small ccdpsf output files with known contents, for exact reader tests."""

import json

import numpy as np
from astropy.io import fits


def write_chain(path, values, log_prob, names, units, burn_in, num_param, new_format=True,
                converged=True, row_order=None, write_nsteps=True):
    """chain.fits from values (steps, walkers, columns) and log_prob (steps, walkers).

    new_format: the shared plan's layout (keywords in the CHAIN header, NPARAM/NDERIVED,
    TUNIT from ``units``); else the older one (keywords in the primary header, no units, every
    value column a parameter). row_order: a permutation of the step-major rows (the reader
    must place rows by their own step and walker columns)."""
    steps, walkers, ncols = values.shape
    step_index = np.repeat(np.arange(steps), walkers)
    walker_index = np.tile(np.arange(walkers), steps)
    flat = values.reshape(steps * walkers, ncols)
    lp = log_prob.reshape(-1)
    if row_order is not None:
        step_index, walker_index, flat, lp = (step_index[row_order], walker_index[row_order],
                                              flat[row_order], lp[row_order])
    columns = [fits.Column(name="walker", format="K", array=walker_index),
               fits.Column(name="step", format="K", array=step_index),
               fits.Column(name="log_prob", format="D", array=lp)]
    for i, name in enumerate(names):
        unit = units[i] if new_format and units[i] else None
        columns.append(fits.Column(name=name, format="D", array=flat[:, i], unit=unit))
    table = fits.BinTableHDU.from_columns(columns, name="CHAIN")
    primary = fits.PrimaryHDU()
    keywords = {"BURNIN": burn_in, "WALKERS": walkers, "CONVERGD": converged}
    if new_format:
        if write_nsteps:
            keywords["NSTEPS"] = steps
        keywords["NPARAM"] = num_param
        keywords["NDERIVED"] = ncols - num_param
        for key, value in keywords.items():
            table.header[key] = value
    else:
        for key, value in keywords.items():
            primary.header[key] = value
    fits.HDUList([primary, table]).writeto(path, overwrite=True)


def write_fit_json(path, parameter_names, derived_names=(), covariance=None):
    """A fit.json with what the reader uses: parameters (sorted, as nlohmann writes them),
    map_vs_mcmc in the model's order, derived, quality, optionally covariance."""
    summary = {"map": 0.0, "laplace_sd": 0.1, "median": 0.0, "lo68": -0.1, "hi68": 0.1,
               "lo997": -0.3, "hi997": 0.3}
    doc = {
        "parameters": {n: dict(summary) for n in sorted(parameter_names)},
        "derived": {n: dict(summary) for n in sorted(derived_names)},
        "map_vs_mcmc": [{"name": n} for n in list(parameter_names) + list(derived_names)],
        "quality": {"verdict": "ok", "reasons": [], "notes": []},
    }
    if covariance is not None:
        doc["covariance"] = covariance
    with open(path, "w") as f:
        json.dump(doc, f, sort_keys=True)
