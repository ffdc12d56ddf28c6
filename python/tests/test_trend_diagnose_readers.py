"""read_trend and read_diagnose on synthetic folders written here (exact checks)."""

import json

import astropy.units as u
import numpy as np
import pytest

import ccdpsf
from synthetic_outputs import write_chain, write_fit_json

TREND_JSON = {
    "relations": {"fwhm_um_vs_wavelength": {"abscissa": "wavelength_nm"},
                  "r2_px2_vs_intensity": {"abscissa": "intensity_e"}},
    "requirements": [
        {"name": "fwhm_800nm", "target": "metric_at", "metric": "fwhm_um", "comparison": "<=",
         "limit": 10.8, "value": 5.5, "lo68": 4.0, "hi68": 7.0, "sd": 1.5, "margin": 5.3,
         "pass": True, "pass_probability": 0.97, "verdict": "pass", "reason": None,
         "at": {"wavelength_nm": 800.0, "intensity_e": 157800.0}, "notes": ["a", "b"]},
        {"name": "alpha_fwhm", "target": "coefficient", "coefficient": "alpha",
         "relation": "fwhm_um_vs_wavelength", "comparison": "<=", "limit": -0.2, "value": -0.3,
         "lo68": -0.5, "hi68": -0.1, "sd": 0.2, "margin": 0.1, "pass": True,
         "pass_probability": None, "verdict": "undetermined", "reason": None},
    ],
    "focus_series_requirements": [],
    "groups": [{"name": "g00", "report": "groups/g00", "failure": None},
               {"name": "g01", "report": None, "failure": "no WAVELEN keyword"}],
}

# Today's relation CSV (generic columns) and the planned one (units in the names).
TODAY_CSV = ("group,abscissa,median,lo68,hi68,sd,normalized_residual,used,upper_limit_95\n"
             "g00,600,6.5,2.5,13.5,4.25,0.125,1,\n"
             "g01,700,,,,,,0,3.75\n")
PLANNED_CSV = ("group,peak_e,r2_px2,r2_px2_lo68,r2_px2_hi68,r2_px2_sd,normalized_residual,used,"
               "r2_px2_upper_limit_95\n"
               "g00,157014.5,0.125,0.0625,0.25,0.5,-0.25,1,\n")
GROUPS_CSV = ("group,wavelength_nm,nominal_peak_e,exposures,focus_series,ok,peak_e,fwhm_um,"
              "fwhm_um_lo68,fwhm_um_hi68,exptime_s,gain_e_per_adu,chi2_per_dof,failure\n"
              "g00,600,160200.000000,3,0,1,157741.5,6.5,3.0,13.5,2.5,3.1,0.96875,\"\"\n"
              "g01,700,,0,0,0,,,,,,,,\"no WAVELEN keyword\"\n")


def make_trend_folder(folder):
    folder.mkdir()
    (folder / "trend.json").write_text(json.dumps(TREND_JSON))
    (folder / "fwhm_um_vs_wavelength.csv").write_text(TODAY_CSV)
    (folder / "r2_px2_vs_intensity.csv").write_text(PLANNED_CSV)
    (folder / "groups.csv").write_text(GROUPS_CSV)
    group = folder / "groups" / "g00"
    group.mkdir(parents=True)
    write_fit_json(group / "fit.json", ["flux_e", "x_px_0"])
    values = np.arange(3 * 2 * 2, dtype=float).reshape(3, 2, 2)
    write_chain(group / "chain.fits", values, -values[:, :, 0], ["flux_e", "x_px_0"],
                ["electron", "pix"], 1, 2)
    return values


def test_relation_tables_with_todays_and_planned_names(tmp_path):
    make_trend_folder(tmp_path / "trend")
    trend = ccdpsf.read_trend(tmp_path / "trend")
    assert set(trend.tables) == {"fwhm_um_vs_wavelength", "r2_px2_vs_intensity", "groups"}
    assert set(trend.relations) == {"fwhm_um_vs_wavelength", "r2_px2_vs_intensity"}
    today = trend.relations["fwhm_um_vs_wavelength"]
    assert today["abscissa"].unit == u.nm  # from trend.json's "abscissa": "wavelength_nm"
    for column in ("median", "lo68", "hi68", "sd", "upper_limit_95"):
        assert today[column].unit == u.um  # the quantity in the file's name
    np.testing.assert_array_equal(today["median"].value, [6.5, np.nan])
    np.testing.assert_array_equal(today["upper_limit_95"].value, [np.nan, 3.75])
    assert list(today["group"]) == ["g00", "g01"]
    np.testing.assert_array_equal(today["used"], [1, 0])
    planned = trend.relations["r2_px2_vs_intensity"]
    assert planned["peak_e"].unit == u.electron
    for column in ("r2_px2", "r2_px2_lo68", "r2_px2_hi68", "r2_px2_sd", "r2_px2_upper_limit_95"):
        assert planned[column].unit == u.pix**2
    assert planned["normalized_residual"].unit == u.dimensionless_unscaled
    assert planned["r2_px2_lo68"][0] == 0.0625 * u.pix**2
    assert np.isnan(planned["r2_px2_upper_limit_95"][0].value)


def test_groups_table_units_and_gaps(tmp_path):
    make_trend_folder(tmp_path / "trend")
    groups = ccdpsf.read_trend(tmp_path / "trend").groups_table
    expected = {"wavelength_nm": u.nm, "nominal_peak_e": u.electron, "peak_e": u.electron,
                "fwhm_um": u.um, "fwhm_um_lo68": u.um, "exptime_s": u.s,
                "gain_e_per_adu": u.electron / u.adu, "chi2_per_dof": u.dimensionless_unscaled}
    for column, unit in expected.items():
        assert groups[column].unit == unit, column
    assert groups["fwhm_um_hi68"][0] == 13.5 * u.um
    assert np.isnan(groups["fwhm_um"][1].value)  # a failed group's empty cell
    np.testing.assert_array_equal(groups["exposures"], [3, 0])
    assert list(groups["failure"]) == ["", "no WAVELEN keyword"]


def test_requirements_from_trend_json(tmp_path):
    make_trend_folder(tmp_path / "trend")
    req = ccdpsf.read_trend(tmp_path / "trend").requirements
    assert list(req["name"]) == ["fwhm_800nm", "alpha_fwhm"]
    np.testing.assert_array_equal(req["limit"], [10.8, -0.2])
    np.testing.assert_array_equal(req["pass_probability"], [0.97, np.nan])
    assert list(req["unit"]) == ["um", ""]
    assert req["at_wavelength_nm"].unit == u.nm
    assert req["at_wavelength_nm"][0] == 800 * u.nm
    assert np.isnan(req["at_intensity_e"][1].value)
    assert list(req["notes"]) == ["a; b", ""]
    assert list(req["pass"]) == [True, True]
    assert len(ccdpsf.read_trend(tmp_path / "trend").focus_series_requirements) == 0


def test_requirements_csv_is_preferred(tmp_path):
    make_trend_folder(tmp_path / "trend")
    (tmp_path / "trend" / "requirements.csv").write_text(
        "name,value_um,limit_um,pass_probability\nfwhm_800nm,5.5,10.8,0.97\n")
    req = ccdpsf.read_trend(tmp_path / "trend").requirements
    assert req["value_um"].unit == u.um
    assert req["limit_um"][0] == 10.8 * u.um


def test_group_fits_are_read_lazily(tmp_path):
    values = make_trend_folder(tmp_path / "trend")
    trend = ccdpsf.read_trend(tmp_path / "trend")
    assert list(trend.groups) == ["g00"]
    assert trend.groups.failures == {"g01": "no WAVELEN keyword"}
    assert trend.groups._fits == {}  # nothing read yet
    np.testing.assert_array_equal(trend.groups["g00"].get_chain(), values[1:])
    with pytest.raises(KeyError, match="no WAVELEN keyword"):
        trend.groups["g01"]
    with pytest.raises(KeyError, match="no group"):
        trend.groups["g99"]


def test_trend_errors(tmp_path):
    with pytest.raises(ccdpsf.OutputMissingError, match="no such folder"):
        ccdpsf.read_trend(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ccdpsf.OutputMissingError, match="trend.json"):
        ccdpsf.read_trend(tmp_path / "empty")


DIAGNOSE_JSON = {
    "verdict": "named", "named_effects": ["serial_cti"], "final_fit": {"chi2": 400.0},
    "attributions": [{"name": "serial_cti", "round": 0, "status": "named", "reason": None}],
    "rounds": [
        {"model": {"description": "baseline", "effects": [], "defocus": True, "flux": "shared"},
         "fit": {"chi2": 500.0, "dof": 400, "parameters": {"flux_e": {"map": 1e5}}},
         "chi2_per_dof": 1.25,
         "statistics": [{"name": "odd_x_z", "value": 4.5, "p_value": 0.001,
                         "predictive_mean": 0.0, "predictive_sd": 1.0, "tail": "two_sided",
                         "p_method": "simulations", "description": "odd moment"},
                        {"name": "peak_trend_z", "value": None, "p_value": None,
                         "predictive_mean": None, "predictive_sd": None, "tail": "two_sided",
                         "p_method": "", "description": "n/a"}],
         "candidates": [{"name": "defocus", "kind": "effect", "status": "in_model",
                         "reason": "already in the model"},
                        {"name": "serial_cti", "kind": "effect", "status": "tested",
                         "delta_loglike": 50.0, "lr": 100.0, "p_value": 1e-20,
                         "delta_bic": -90.0, "log_bayes_factor": 45.0, "significant": True,
                         "nested": True, "num_parameters": 2, "chi2_per_dof_with": 1.0}],
         "radial_profile": {"annulus_inner_px": [0, 1], "mean_normalised_residual": [0.5, None],
                            "count": [5, 8]},
         "adopted": "serial_cti", "rivals": [], "verdict": "adopted serial_cti",
         "tested": True, "num_tested": 8, "p_threshold": 0.00125},
        {"model": {"description": "baseline + serial_cti", "effects": ["serial_cti"]},
         "fit": {"chi2": 400.0, "dof": 398}, "chi2_per_dof": 1.005, "statistics": [],
         "candidates": [], "radial_profile": {}, "adopted": None, "rivals": [],
         "verdict": "nothing more to add", "tested": True, "num_tested": 7,
         "p_threshold": 0.0014},
    ],
}


def test_read_diagnose_rounds(tmp_path):
    (tmp_path / "diag").mkdir()
    (tmp_path / "diag" / "diagnose.json").write_text(json.dumps(DIAGNOSE_JSON))
    diag = ccdpsf.read_diagnose(tmp_path / "diag")
    assert diag.verdict == "named" and diag.named_effects == ["serial_cti"]
    assert diag.final_fit == {"chi2": 400.0}
    assert len(diag.rounds) == 2
    first, second = diag.rounds
    assert (first.index, first.model_description, first.effects) == (0, "baseline", [])
    assert first.adopted == "serial_cti" and second.adopted is None
    assert second.effects == ["serial_cti"] and second.chi2_per_dof == 1.005
    assert first.parameters == {"flux_e": {"map": 1e5}}
    stats = first.statistics
    assert list(stats["name"]) == ["odd_x_z", "peak_trend_z"]
    np.testing.assert_array_equal(stats["value"], [4.5, np.nan])
    cand = first.candidates_table
    assert list(cand["status"]) == ["in_model", "tested"]
    np.testing.assert_array_equal(cand["delta_bic"], [np.nan, -90.0])
    assert list(cand["significant"]) == [False, True]
    np.testing.assert_array_equal(first.radial_profile["mean_normalised_residual"], [0.5, np.nan])
    assert len(second.statistics) == 0 and len(second.candidates_table) == 0


def test_diagnose_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ccdpsf.OutputMissingError, match="diagnose.json"):
        ccdpsf.read_diagnose(tmp_path / "empty")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "diagnose.json").write_text('{"rounds": 3}')
    with pytest.raises(ccdpsf.OutputFormatError, match="rounds"):
        ccdpsf.read_diagnose(tmp_path / "bad")
