// Relations per spot across a grid campaign's settings: how each spot's PSF changes with
// wavelength (and with intensity at one wavelength), and so how those relations vary across
// the sensor.
//
// A spot is followed across settings by position: the spots of every setting within
// match_radius_px of a spot of the first setting holding it (the projector's grid does not
// move between settings; greedy, nearest first, each spot taken once) form a track. For each
// track and metric, trend's relations (trend/relations.h) are fitted to the spot's posterior
// draws in each setting (with --nomcmc: a Gaussian of the MAP and its Laplace sd):
//   vs wavelength: a power law over one setting per wavelength, the one whose peak-pixel
//                  intensity is nearest trend's I0 (157 800 e-);
//   vs intensity:  a line in the peak-pixel intensity over the settings of one wavelength,
//                  for each wavelength with two or more settings.
// A spot that was refused, failed or whose verdict is invalid is a gap with its reason, as a
// failed setting is in trend; a suspect one is used (its verdict is in psf_map).
#ifndef CCDPSF_GRID_SPOT_RELATIONS_H_
#define CCDPSF_GRID_SPOT_RELATIONS_H_

#include <string>
#include <vector>

#include "ccdpsf/grid/grid.h"
#include "ccdpsf/trend/relations.h"

namespace ccdpsf::grid {

// The metrics related per spot: the identified total FWHM always; the CCD kernel's FWHM
// (identified only by through-focus settings; flagged poorly constrained otherwise).
const std::vector<std::string>& SpotRelationMetrics();

struct SpotRelation {
  int track = 0;                  // the spot followed across settings
  double x_px = 0.0, y_px = 0.0;  // its position in the first setting holding it [px]
  std::string metric;
  trend::RelationKind kind = trend::RelationKind::kPowerLaw;
  double wavelength_nm = NAN;  // of an intensity relation; NaN for wavelength relations
  std::vector<int> spots;      // psf_map spot numbers of the points, input order
  trend::RelationFit fit;
};

// Every track's relations, tracks in the order of their first spot; none when the campaign
// has a single setting. Relation k's resampling seed is DeriveSeed(options.seed, k).
std::vector<SpotRelation> FitSpotRelations(const GridResult& result, double match_radius_px,
                                           const trend::RelationOptions& options);

}  // namespace ccdpsf::grid

#endif  // CCDPSF_GRID_SPOT_RELATIONS_H_
