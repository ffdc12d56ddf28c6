#!/usr/bin/python3
"""Writes the seed corpus of fuzz/text_input_fuzzer.cc into fuzz/text_corpus/.

Each seed is one byte choosing the reader (the harness's enum Reader, in its order) and the
text: a FIT.json, CSV and JSON manifests (rows and groups, a bad-pixel mask), the testdata
simulation and campaign configs, a requirements list, keyword maps as text and as JSON, an
effect list, IRAF sections, a truth file, a stored group result and a ptc.json (--ptc). Deterministic, standard
library only:
    /usr/bin/python3 fuzz/make_text_corpus.py
"""

import os

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "text_corpus")
TESTDATA = os.path.join(HERE, "..", "testdata")

(FIT_CONFIG, MANIFEST_CSV, MANIFEST_JSON, SIMULATION, CAMPAIGN, REQUIREMENTS, KEYWORDS_TEXT,
 KEYWORDS_FILE, EFFECTS, SECTION, TRUTH, GROUP_RESULT, PTC_PRIOR) = range(13)


def testdata(name):
    with open(os.path.join(TESTDATA, name), encoding="utf-8") as f:
        return f.read()


SEEDS = {
    "fit_config.json": (FIT_CONFIG, """{"sampling": "pixel_centre", "joint": true,
 "priors": {"airy_radius_px": [0.2, 1.0]}, "mcmc": {"seed": 9, "walkers": 40},
 "calibration": {"gain_e_per_adu": 2.5, "stamp_size": 15, "bias_section": "[1:10,*]"},
 "keywords": {"exptime_s": {"keyword": "EXPMS", "scale": 0.001}},
 "effects": {"serial_cti": {}}, "flags": {"outliers": false, "pixel_um": 12}}"""),
    "manifest.csv": (MANIFEST_CSV, """file,setting,exptime_s,gain_e_per_adu,bad_pixel_mask
# a comment
a.fits,s800,1.5,2.0,mask.fits
"b c.fits",s800,1.5,2.0,
../d.fits,"s,900",2,2.0,
"""),
    "manifest_rows.json": (MANIFEST_JSON, """{"exposures": [
 {"file": "a.fits", "setting": "g1", "exptime_s": 0.1, "hdu": "AMP1"},
 {"file": "sub/b.fits", "setting": "../../x", "bad_pixel_mask": "m.fits"}]}"""),
    "manifest_groups.json": (MANIFEST_JSON, testdata("campaign_small/manifest.json")),
    "simulation.json": (SIMULATION, testdata("demo_simulation.json")),
    "campaign.json": (CAMPAIGN, testdata("campaign_small.json")),
    "requirements.json": (REQUIREMENTS, """[{"name": "fwhm_800nm", "metric": "fwhm_um",
  "at": {"wavelength_nm": 800, "intensity_e": 157800}, "max": 10.8},
 {"name": "alpha_fwhm", "relation": "fwhm_um_vs_wavelength", "coefficient": "alpha",
  "max": -0.2}]"""),
    "keywords.txt": (KEYWORDS_TEXT, "gain_e_per_adu=EGAIN,exptime_s=EXPMS*0.001,bias_adu=-"),
    "keywords.json": (KEYWORDS_FILE,
                      '{"gain_e_per_adu": "EGAIN", "exptime_s": {"keyword": "EXPMS", '
                      '"scale": 0.001}}'),
    "effects.txt": (EFFECTS, "serial_cti,parallel_cti,ipc,background,halo"),
    "section.txt": (SECTION, "[1:2048, 10:*]"),
    "section_reversed.txt": (SECTION, "[20:1,*]"),
    "truth.json": (TRUTH, """{"seed": 1, "noiseless": false,
 "exposures": [{"file": "exposure_000.fits", "flux_e": 1e5, "airy_radius_px": 0.8}]}"""),
    "group_result.json": (GROUP_RESULT, """{"format": 5, "group": "g1", "ok": true,
 "failure": "", "exposures": 3, "seconds": 1.5, "summaries": {"sigma_x_px":
 [0.4, 0.01, 0.4, 0.39, 0.41, 0.37, 0.43]}, "draws": {"sigma_x_px": [0.4, "nan"]},
 "report_dir": "groups/g1"}"""),
    "ptc.json": (PTC_PRIOR, """{"a": {"a_00": {"median": -1.2e-6, "sd": 5e-8},
 "a_10": {"median": 1.5e-7, "sd": 2e-8}, "a_01": {"median": 2e-7, "sd": 2e-8},
 "a_11": {"median": 6e-8, "sd": 1e-8}},
 "a_covariance": {"names": ["a_00", "a_10", "a_01", "a_11"], "matrix": [[2.5e-15, 0, 0, 0],
 [0, 4e-16, 1.2e-16, 0], [0, 1.2e-16, 4e-16, 0], [0, 0, 0, 1e-16]], "unit": "1/e-^2"}}"""),
}


def main():
    os.makedirs(OUT, exist_ok=True)
    for name, (reader, text) in sorted(SEEDS.items()):
        with open(os.path.join(OUT, name), "wb") as f:
            f.write(bytes([reader]) + text.encode("utf-8"))


if __name__ == "__main__":
    main()
