"""The readers on what the real binary writes (CCDPSF_BINARY; skipped without it).

The checks are independent of the reader's own arithmetic: fit.json's posterior summaries are
recomputed from get_chain with the C++ definition (src/fit/fit.cc: non-finite draws dropped,
linear interpolation between order statistics at q (n - 1), the 68.27 % interval at
q = 0.158655 / 0.841345), and the chain's grid is compared with chain.fits's rows as astropy
reads them."""

import json

import astropy.units as u
import numpy as np
import pytest
from astropy.table import Table

import ccdpsf

from conftest import REPO_DIR

# fit.json holds doubles printed to round-trip exactly, chain.fits holds the same doubles; the
# interpolation formula differs from numpy's only in rounding: a few ulps.
SUMMARY_RTOL = 1e-12


def cpp_percentile(values, q):
    values = np.sort(values[np.isfinite(values)])
    # numpy's "linear" method is the same definition: position q (n - 1).
    return np.quantile(values, q, method="linear")


def test_chain_reproduces_fit_json_summaries(real_fit_folder):
    fit = ccdpsf.read_fit(real_fit_folder)
    summary = json.loads((real_fit_folder / "fit.json").read_text())
    assert fit.burn_in == summary["mcmc"]["burn_in"]
    assert fit.walkers == summary["mcmc"]["walkers"]
    assert fit.steps == summary["mcmc"]["steps"]
    flat = fit.get_chain(flat=True)
    assert flat.shape == ((fit.steps - fit.burn_in) * fit.walkers, len(summary["parameters"]))
    assert sorted(fit.names) == sorted(summary["parameters"])
    for i, name in enumerate(fit.names):
        expected = summary["parameters"][name]
        for key, q in (("median", 0.5), ("lo68", 0.158655), ("hi68", 0.841345),
                       ("lo997", 0.00135), ("hi997", 0.99865)):
            np.testing.assert_allclose(cpp_percentile(flat[:, i], q), expected[key],
                                       rtol=SUMMARY_RTOL, err_msg=f"{name} {key}")


# astropy's own FITS reader warns that TUNIT 'electron' is not a FITS-standard unit (the
# package's reader parses it with astropy's generic parser instead).
@pytest.mark.filterwarnings("ignore::astropy.units.UnitsWarning")
def test_chain_grid_matches_walker_and_step_columns(real_fit_folder):
    fit = ccdpsf.read_fit(real_fit_folder)
    rows = Table.read(real_fit_folder / "chain.fits", hdu="CHAIN")
    whole = fit.get_chain(discard=0)
    log_prob = fit.get_log_prob(discard=0)
    walker, step = np.asarray(rows["walker"]), np.asarray(rows["step"])
    assert len(rows) == fit.walkers * fit.steps
    np.testing.assert_array_equal(log_prob[step, walker], rows["log_prob"])
    for i, column in enumerate(fit.column_names[:len(fit.names)]):
        np.testing.assert_array_equal(whole[step, walker, i], rows[column])
    # The table is the post-burn-in rows of the file, in the file's order.
    kept = rows[step >= fit.burn_in]
    table = fit.table
    np.testing.assert_array_equal(table["walker"], kept["walker"])
    np.testing.assert_array_equal(table["step"], kept["step"])
    for name, column in zip(fit.names + fit.derived_names, fit.column_names):
        np.testing.assert_array_equal(table[name].value, kept[column])
    assert table["flux_e"].unit == u.electron
    assert table["airy_radius_px"].unit == u.pix
    assert table[fit.names[5]].unit == u.pix  # exposure 0's x position


def test_residuals_are_data_minus_model(real_fit_folder):
    res = ccdpsf.read_fit(real_fit_folder).residuals
    assert len(res) == 2
    for k in range(2):
        data, model, resid = res.data(k), res.model(k), res.resid(k)
        valid = np.isfinite(data)
        assert valid.sum() > 0.9 * data.size
        # The same double subtraction the C++ does: exact.
        np.testing.assert_array_equal(resid[valid], data[valid] - model[valid])
        assert np.all(np.isnan(resid[~valid]))


def test_covariance_is_symmetric_when_present(real_fit_folder):
    cov = ccdpsf.read_fit(real_fit_folder).covariance
    if cov is None:
        pytest.skip("this binary's fit.json has no covariance yet")
    np.testing.assert_array_equal(cov.matrix, cov.matrix.T)
    assert np.all(np.diag(cov.matrix) > 0)


def test_run_fit_and_its_errors(ccdpsf_binary, simulated_exposures, tmp_path):
    fit = ccdpsf.run("fit", *simulated_exposures, out=tmp_path / "nomcmc", joint=True,
                     mcmc=False, binary=ccdpsf_binary)
    assert isinstance(fit, ccdpsf.FitResult)
    assert fit.summary["mcmc"] is None
    with pytest.raises(ccdpsf.NoChainError, match="--nomcmc"):
        fit.get_chain()
    with pytest.raises(ccdpsf.RunError) as info:
        ccdpsf.run("fit", tmp_path / "missing.fits", out=tmp_path / "bad", binary=ccdpsf_binary)
    assert info.value.exit_code == 1
    assert "missing.fits" in info.value.message and "\n" not in info.value.message
    with pytest.raises(ccdpsf.RunError) as info:
        ccdpsf.run("fit", *simulated_exposures, out=tmp_path / "bad", binary=ccdpsf_binary,
                   no_such_option=3)
    assert info.value.exit_code == 2
    assert "no_such_option" in info.value.message


def test_trend_tables_match_trend_json(real_trend_folder):
    trend = ccdpsf.read_trend(real_trend_folder)
    summary = json.loads((real_trend_folder / "trend.json").read_text())
    assert set(trend.relations) == set(summary["relations"])
    # CSVs are written with 10 significant digits.
    csv_rtol = 1e-9
    for name, relation in summary["relations"].items():
        table = trend.relations[name]
        points = {p["label"]: p for p in relation["points"]}
        value_column = "median" if "median" in table.colnames else name.split("_vs_")[0]
        for row in table:
            point = points.get(str(row["group"]))
            if point is None:
                continue  # a gap
            np.testing.assert_allclose(row[value_column].value, point["value"]["median"],
                                       rtol=csv_rtol)
    groups = trend.groups_table
    assert groups["wavelength_nm"].unit == u.nm
    assert groups["fwhm_um"].unit == u.um
    assert len(groups) == len(summary["groups"])
    requirements = trend.requirements
    assert list(requirements["name"]) == [r["name"] for r in summary["requirements"]]
    # Each group's fit is read on demand and is the group's own.
    name = summary["groups"][0]["name"]
    group_fit = trend.groups[name]
    group_summary = json.loads((real_trend_folder / "groups" / name / "fit.json").read_text())
    flat = group_fit.get_chain(flat=True)
    i = group_fit.names.index("airy_radius_px")
    np.testing.assert_allclose(cpp_percentile(flat[:, i], 0.5),
                               group_summary["parameters"]["airy_radius_px"]["median"],
                               rtol=SUMMARY_RTOL)


def test_run_grid_reads_the_map_with_units(ccdpsf_binary, tmp_path):
    """A 512 x 512 pair of frames with a 2 x 2 grid by the independent script
    (tests/support/grid_frames.py): read_grid's QTables against psf_map.csv as plain text."""
    import subprocess
    import sys
    frames = tmp_path / "frames"
    subprocess.run([sys.executable, str(REPO_DIR / "tests/support/grid_frames.py"), str(frames),
                    "--size", "512", "--grid", "2", "--exposures", "2", "--no_extras"],
                   check=True, capture_output=True)
    grid = ccdpsf.run("grid", *sorted(frames.glob("frame_*.fits")), out=tmp_path / "grid",
                      mcmc=False, binary=ccdpsf_binary)
    assert isinstance(grid, ccdpsf.GridResult)
    assert len(grid.psf_map) == 4 and len(grid.ok) == 4
    assert grid.psf_map["total_fwhm_um"].unit == u.um
    # The interval's bounds carry the metric's unit, so that centre - bound is a Quantity.
    for bound in ("total_fwhm_um_lo68", "total_fwhm_um_hi68"):
        assert grid.psf_map[bound].unit == u.um, bound
    assert np.all(grid.psf_map["total_fwhm_um"] - grid.psf_map["total_fwhm_um_lo68"] >= 0 * u.um)
    assert grid.psf_map["x_px"].unit == u.pix
    assert "Laplace" in grid.interval
    plain = Table.read(tmp_path / "grid" / "psf_map.csv", format="ascii.csv")
    np.testing.assert_array_equal(grid.psf_map["total_fwhm_um"].value, plain["total_fwhm_um"])
    assert list(grid.psf_map["verdict"]) == list(plain["verdict"])
    assert len(grid.catalogue) == 8  # four spots in each of two frames
    assert grid.relations is None    # one setting: no relations across settings
