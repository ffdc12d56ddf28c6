"""read_fit on synthetic fit folders with a known chain: every check is exact (the reader only
moves numbers, so equality, not closeness, is the right test)."""

import json

import astropy.units as u
import emcee
import numpy as np
import pytest
from astropy.io import fits

import ccdpsf
from synthetic_outputs import write_chain, write_fit_json

STEPS, WALKERS = 12, 4
PARAMS = ["flux_e", "airy_radius_px", "x_px.0", "flux_ratio.1"]  # internal names
DERIVED = ["fwhm_um", "r2_px2", "ellipticity"]
BURN_IN = 5


def known_chain():
    """values[s, w, i] = 1000 s + 10 w + i encodes its own position; log_prob likewise."""
    s, w, i = np.meshgrid(np.arange(STEPS), np.arange(WALKERS),
                          np.arange(len(PARAMS) + len(DERIVED)), indexing="ij")
    values = 1000.0 * s + 10.0 * w + i
    log_prob = -(1000.0 * np.arange(STEPS)[:, None] + 10.0 * np.arange(WALKERS)[None, :])
    return values, log_prob


def make_fit_folder(folder, new_format=True, shuffle=False, covariance=None):
    folder.mkdir(parents=True, exist_ok=True)
    values, log_prob = known_chain()
    if new_format:
        names = [ccdpsf.units.fits_valid_name(n) for n in PARAMS + DERIVED]
        units = ["electron", "pix", "pix", "", "um", "pix2", ""]
        stored = values
    else:
        names, units, stored = PARAMS, [None] * len(PARAMS), values[:, :, :len(PARAMS)]
    order = np.random.default_rng(3).permutation(STEPS * WALKERS) if shuffle else None
    write_chain(folder / "chain.fits", stored, log_prob, names, units, BURN_IN, len(PARAMS),
                new_format=new_format, row_order=order)
    write_fit_json(folder / "fit.json", PARAMS, DERIVED, covariance)
    return values, log_prob


@pytest.mark.parametrize("new_format", [True, False])
@pytest.mark.parametrize("shuffle", [False, True])
def test_get_chain_is_numpy_slicing_of_the_known_array(tmp_path, new_format, shuffle):
    values, log_prob = make_fit_folder(tmp_path / "fit", new_format, shuffle)
    fit = ccdpsf.read_fit(tmp_path / "fit")
    params = values[:, :, :len(PARAMS)]
    assert fit.names == PARAMS
    assert (fit.walkers, fit.steps, fit.burn_in) == (WALKERS, STEPS, BURN_IN)
    np.testing.assert_array_equal(fit.get_chain(), params[BURN_IN:])
    np.testing.assert_array_equal(fit.get_log_prob(), log_prob[BURN_IN:])
    np.testing.assert_array_equal(fit.log_prob, log_prob[BURN_IN:])
    for discard in (0, 3, BURN_IN, STEPS - 1):
        for thin in (1, 2, 5):
            # emcee's definition: the first step kept is discard + thin - 1.
            expected = params[discard + thin - 1::thin]
            np.testing.assert_array_equal(fit.get_chain(discard=discard, thin=thin), expected)
            np.testing.assert_array_equal(
                fit.get_chain(discard=discard, thin=thin, flat=True),
                expected.reshape(-1, len(PARAMS)))
            np.testing.assert_array_equal(fit.get_log_prob(discard=discard, thin=thin, flat=True),
                                          log_prob[discard + thin - 1::thin].reshape(-1))
    if new_format:
        assert fit.derived_names == DERIVED
        np.testing.assert_array_equal(fit.get_derived(), values[BURN_IN:, :, len(PARAMS):])
    else:
        assert fit.derived_names == []
        assert fit.get_derived().shape == (STEPS - BURN_IN, WALKERS, 0)


def test_get_chain_agrees_with_emcee_backend(tmp_path):
    """The same chain stored in emcee's own backend gives the same arrays for every discard,
    thin and flat: an independent statement of emcee's convention."""
    values, log_prob = make_fit_folder(tmp_path / "fit")
    fit = ccdpsf.read_fit(tmp_path / "fit")
    params = values[:, :, :len(PARAMS)]
    backend = emcee.backends.Backend()
    backend.reset(WALKERS, len(PARAMS))
    backend.grow(STEPS, None)
    for s in range(STEPS):
        backend.save_step(emcee.State(params[s], log_prob=log_prob[s]), np.ones(WALKERS, bool))
    for discard in (0, 2, BURN_IN):
        for thin in (1, 3):
            for flat in (False, True):
                np.testing.assert_array_equal(
                    fit.get_chain(discard=discard, thin=thin, flat=flat),
                    backend.get_chain(discard=discard, thin=thin, flat=flat))
                np.testing.assert_array_equal(
                    fit.get_log_prob(discard=discard, thin=thin, flat=flat),
                    backend.get_log_prob(discard=discard, thin=thin, flat=flat))


@pytest.mark.parametrize("new_format", [True, False])
def test_table_rows_units_and_order(tmp_path, new_format):
    values, log_prob = make_fit_folder(tmp_path / "fit", new_format, shuffle=True)
    table = ccdpsf.read_fit(tmp_path / "fit").table
    kept = STEPS - BURN_IN
    assert len(table) == kept * WALKERS
    np.testing.assert_array_equal(table["step"], np.repeat(np.arange(BURN_IN, STEPS), WALKERS))
    np.testing.assert_array_equal(table["walker"], np.tile(np.arange(WALKERS), kept))
    np.testing.assert_array_equal(table["log_prob"], log_prob[table["step"], table["walker"]])
    # Units: TUNIT in the new layout, the names' suffixes in the older one; the same either way.
    expected_units = {"flux_e": u.electron, "airy_radius_px": u.pix, "x_px.0": u.pix,
                      "flux_ratio.1": u.dimensionless_unscaled}
    for i, name in enumerate(PARAMS):
        assert table[name].unit == expected_units[name]
        np.testing.assert_array_equal(table[name].value,
                                      values[table["step"], table["walker"], i])
    if new_format:
        assert table["fwhm_um"].unit == u.um
        assert table["r2_px2"].unit == u.pix**2
        assert table["ellipticity"].unit == u.dimensionless_unscaled
        np.testing.assert_array_equal(table["r2_px2"].value,
                                      values[table["step"], table["walker"], 5])
    else:
        assert "fwhm_um" not in table.colnames


def test_column_names_map_to_fit_json_names(tmp_path):
    make_fit_folder(tmp_path / "fit", new_format=True)
    fit = ccdpsf.read_fit(tmp_path / "fit")
    assert fit.column_names[:len(PARAMS)] == ["flux_e", "airy_radius_px", "x_px_0", "flux_ratio_1"]
    assert fit.names == PARAMS
    assert set(fit.names) == set(fit.summary["parameters"])


def test_arviz_dict_is_walkers_by_steps(tmp_path):
    values, log_prob = make_fit_folder(tmp_path / "fit")
    d = ccdpsf.read_fit(tmp_path / "fit").to_arviz_dict()
    assert set(d) == {"posterior", "sample_stats"}
    assert list(d["posterior"]) == PARAMS + DERIVED
    for i, name in enumerate(PARAMS + DERIVED):
        np.testing.assert_array_equal(d["posterior"][name], values[BURN_IN:, :, i].T)
    np.testing.assert_array_equal(d["sample_stats"]["lp"], log_prob[BURN_IN:].T)


def test_covariance(tmp_path):
    names = ["flux_e", "airy_radius_px"]
    matrix = [[4.0, 0.5], [0.5, 0.25]]
    make_fit_folder(tmp_path / "fit", covariance={"names": names, "matrix": matrix})
    cov = ccdpsf.read_fit(tmp_path / "fit").covariance
    assert cov.names == names
    np.testing.assert_array_equal(cov.matrix, np.array(matrix))
    make_fit_folder(tmp_path / "bare")
    assert ccdpsf.read_fit(tmp_path / "bare").covariance is None


def test_nomcmc_fit_reads_but_has_no_chain(tmp_path):
    folder = tmp_path / "fit"
    folder.mkdir()
    write_fit_json(folder / "fit.json", PARAMS, DERIVED)
    fit = ccdpsf.read_fit(folder)
    assert fit.names == PARAMS  # from fit.json's map_vs_mcmc order
    assert not fit.has_chain
    with pytest.raises(ccdpsf.NoChainError, match="--nomcmc"):
        fit.get_chain()
    with pytest.raises(ccdpsf.NoChainError):
        fit.table


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ccdpsf.OutputMissingError, match="no such folder"):
        ccdpsf.read_fit(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ccdpsf.OutputMissingError, match="fit.json"):
        ccdpsf.read_fit(tmp_path / "empty")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "fit.json").write_text("{not json")
    with pytest.raises(ccdpsf.OutputFormatError, match="not valid JSON"):
        ccdpsf.read_fit(tmp_path / "bad")
    # One fit per file (fit without --joint): the error names the subfolders.
    make_fit_folder(tmp_path / "several" / "exposure_000")
    with pytest.raises(ccdpsf.OutputMissingError, match="exposure_000"):
        ccdpsf.read_fit(tmp_path / "several")
    # A chain whose rows do not fill the grid.
    make_fit_folder(tmp_path / "short")
    with fits.open(tmp_path / "short" / "chain.fits", mode="update") as hdul:
        hdul[1].header["WALKERS"] = WALKERS + 1
    with pytest.raises(ccdpsf.OutputFormatError, match="rows"):
        ccdpsf.read_fit(tmp_path / "short").get_chain()
    # NPARAM that does not match the columns.
    make_fit_folder(tmp_path / "nparam")
    with fits.open(tmp_path / "nparam" / "chain.fits", mode="update") as hdul:
        hdul[1].header["NPARAM"] = len(PARAMS) + 1
    with pytest.raises(ccdpsf.OutputFormatError, match="NPARAM"):
        ccdpsf.read_fit(tmp_path / "nparam").get_chain()
    good = ccdpsf.read_fit(tmp_path / "several" / "exposure_000")
    with pytest.raises(ValueError, match="thin"):
        good.get_chain(thin=0)
    with pytest.raises(ValueError, match="discard"):
        good.get_chain(discard=-1)


def test_duplicate_rows_are_refused(tmp_path):
    folder = tmp_path / "fit"
    make_fit_folder(folder)
    with fits.open(folder / "chain.fits", mode="update") as hdul:
        hdul[1].data["step"][1] = hdul[1].data["step"][0]
        hdul[1].data["walker"][1] = hdul[1].data["walker"][0]
    with pytest.raises(ccdpsf.OutputFormatError, match="twice"):
        ccdpsf.read_fit(folder).get_chain()


def test_residuals(tmp_path):
    folder = tmp_path / "fit"
    make_fit_folder(folder)
    rng = np.random.default_rng(5)
    hdus = [fits.PrimaryHDU()]
    images = {}
    for k in range(2):
        for kind in ("DATA", "MODEL", "RESID", "NRESID"):
            image = rng.normal(size=(21, 21))
            images[f"{kind}_{k}"] = image
            hdu = fits.ImageHDU(image, name=f"{kind}_{k}")
            hdu.header["SOURCE"] = "%C3%A9t%C3%A9/spot%25.fits"
            hdu.header["LTV1"] = -22.0
            hdu.header["LTV2"] = -14.0
            hdus.append(hdu)
    fits.HDUList(hdus).writeto(folder / "residuals.fits")
    res = ccdpsf.read_fit(folder).residuals
    assert len(res) == 2
    np.testing.assert_array_equal(res.data(1), images["DATA_1"])
    np.testing.assert_array_equal(res.model(0), images["MODEL_0"])
    np.testing.assert_array_equal(res.resid(1), images["RESID_1"])
    np.testing.assert_array_equal(res.nresid(0), images["NRESID_0"])
    np.testing.assert_array_equal(res["model_1"], images["MODEL_1"])
    assert res.exposures[1] == {"index": 1, "source": "été/spot%.fits", "origin_px": (22.0, 14.0)}
    with pytest.raises(KeyError, match="DATA_7"):
        res.data(7)
    (folder / "residuals.fits").unlink()
    with pytest.raises(ccdpsf.OutputMissingError):
        ccdpsf.read_fit(folder).residuals.data(0)


def test_effect_parameter_units():
    """A fitted effect's parameter takes the unit of its own name, after the dot."""
    from ccdpsf.units import unit_from_name

    assert unit_from_name("serial_cti.trail_length_px", indexed=True) == u.pix
    assert unit_from_name("serial_cti.trail_fraction", indexed=True) == u.dimensionless_unscaled
    assert unit_from_name("brighter_fatter.slope_x_px_per_e", indexed=True) == u.pix / u.electron
    assert unit_from_name("nonlinearity.beta_per_e", indexed=True) == 1 / u.electron
    assert unit_from_name("background.pedestal_e", indexed=True) == u.electron
    assert unit_from_name("x_px.3", indexed=True) == u.pix
