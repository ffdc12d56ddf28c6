// What `ccdpsf grid` writes (docs/formats.md, "grid"):
//
//   psf_map.fits / psf_map.csv   one row per spot: where it is, its PSF metrics with 68 %
//                                intervals, its verdict; refused spots with the reason
//   catalogue.fits / .csv        one row per source per frame: detection measures, the spot
//                                it belongs to, whether it was fitted or why not
//   spots.reg                    DS9 regions of the first frame of each setting's spots:
//                                green fitted, red refused, labelled
//   map_total_fwhm.png, map_total_ellipticity.png (and the CCD widths' maps for
//                                through-focus settings): the metrics across the sensor
//   segments.csv                 per setting and segment: spots fitted, median metrics
//   spot_relations.fits / .csv   campaigns of several settings: each spot's relations with
//                                wavelength and intensity (spot_relations.h), and a map of
//                                alpha of the identified FWHM across the sensor
//
// With effects fitted (--effects), psf_map also holds each effect parameter
// (serial_cti_trail_fraction, ...: the fit's name with '.' as '_') with its interval, and a map
// of each across the sensor: an effect that varies over the device (serial CTI grows with the
// transfers to the output) is seen where it changes.
//
// Metric columns carry the posterior median and central 68 % interval (MCMC), or, with
// --nomcmc, the MAP +- its Laplace sd (header keyword INTERVAL says which). total_* are the
// identified widths (defocus and CCD kernel together); fwhm_um, ellipticity, ccd_sigma_* are
// the CCD kernel's alone, which a single focus does not identify (trust them from
// through-focus settings: column `focus_series`).
#ifndef CCDPSF_GRID_PSF_MAP_H_
#define CCDPSF_GRID_PSF_MAP_H_

#include <string>
#include <vector>

#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/grid/grid.h"
#include "ccdpsf/grid/spot_relations.h"
#include "ccdpsf/plot.h"

namespace ccdpsf::grid {

struct PsfMapOutputs {
  std::vector<std::string> files;     // written, in the folder
  std::vector<std::string> warnings;  // plots not made, with why
};

// The metrics of psf_map, in column order, each followed by _lo68 and _hi68.
const std::vector<std::string>& PsfMapMetrics();

// The fitted effects' parameters as the fit names them ("serial_cti.trail_fraction", ...),
// in catalogue order: psf_map's effect columns.
std::vector<std::string> EffectParameterNames(const std::vector<fit::FitEffect>& effects);

// Writes everything above into `dir`; `effects` are the effects every spot's fit holds. False
// with a reason when a file cannot be written.
bool WritePsfMap(const std::string& dir, const GridResult& result,
                 const std::vector<SpotRelation>& relations,
                 const std::vector<fit::FitEffect>& effects, bool have_mcmc,
                 const PlotOptions& plot, PsfMapOutputs* outputs, std::string* error);

}  // namespace ccdpsf::grid

#endif  // CCDPSF_GRID_PSF_MAP_H_
