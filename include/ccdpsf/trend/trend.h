// From the fitted groups of a campaign to the PSF's relations with wavelength and intensity,
// the combined model and the requirement checks (paper section 4).
//
// Which groups feed which relation:
//   <metric>_vs_intensity   the groups at the reference wavelength (800 nm by default; else
//                           the wavelength with the most groups), abscissa the group's
//                           measured peak pixel (posterior median, e-). Every other
//                           wavelength with >= 2 groups measuring the metric gets its own
//                           relation (intensity_by_wavelength).
//   <metric>_vs_wavelength  per wavelength, the group whose peak is nearest the reference
//                           intensity I0 (and within intensity_tolerance of it), corrected
//                           to I0 with the reference wavelength's intensity relation:
//                           X(I0, lambda) = X(I, lambda) X_I(I0) / X_I(I), the paper's
//                           combined-model assumption (section 4.4), draw by draw, so the
//                           correction's own uncertainty is carried. Without an intensity
//                           relation the points are used as measured (noted). For a CCD-only
//                           metric a through-focus series within the tolerance is chosen
//                           before a single-focus setting.
//   through-focus groups    in the relations of the CCD-only metrics (fwhm_um, fwhm_x_um,
//                           fwhm_y_um, r2_px2, ellipticity), where their CCD widths are
//                           identified (a single focus with a Gaussian defocus identifies
//                           only their sum with the defocus, docs/trust.md); not in the
//                           total_* relations, since a series' total PSF is the one at best
//                           focus, not the single-focus settings' defocused spot. The metric
//                           requirements at a series' wavelength are also judged on its own
//                           draws, at its own intensity (focus_requirements).
//   anchored groups         single-focus settings whose defocus a series anchored
//                           (defocus_anchor.h; ccd_split_unidentified is false): in every
//                           relation, as single-focus settings.
// Failed groups appear as gaps in every relation they would have fed.
//
// "Bound only": a group whose MAP puts a CCD width at its prior's lower bound, or, in
// pixel_centre sampling, whose posterior reaches it (group_fit.h unbounded_below), is a gap, with
// its posterior median and 84th percentile in the reason, in the relations of the CCD-only
// metrics that width enters (fwhm_x_um: sigma_x; fwhm_y_um: sigma_y; fwhm_um, r2_px2,
// ellipticity: either); its total_* metrics stay in. Why: in pixel_centre sampling a CCD
// width below ~0.25 px leaves no trace (the sampled kernel is a delta; measured on a 23.4 ke-
// Table-1 setting: log L changes by 0.005 from 0.05 to 0.2 px, then by 60 by 0.3 px), so a
// low-signal setting's posterior is flat down to the prior's edge and its median describes
// the prior. As points, such settings pulled the Table-1 800 nm line down at low intensity
// (slope +1.0 to +1.65 sd in three runs). In integrated sampling the CCD widths trade against
// the defocus along a ridge whose MAP end is at zero defocus, not at the widths' bound: those
// stay in, with prior-wide intervals (docs/trust.md, single focus). A bound-only gap whose chain
// converged carries the 95th percentile of its draws (corrected to I0 like a point) as an upper
// limit: in trend.json's gaps, the relation CSVs and the plots (a downward arrow). It is a
// Bayesian limit of a posterior that is flat from the prior's lower bound up to the wall, so
// it moves with that bound; a true width at the wall can sit just above it (a Table-1
// 23.4 ke- setting: limit 0.235 px in sigma, truth 0.245 px, log L of the truth 0.25 below
// the best).
#ifndef CCDPSF_TREND_TREND_H_
#define CCDPSF_TREND_TREND_H_

#include <map>
#include <string>
#include <vector>

#include "ccdpsf/trend/group_fit.h"
#include "ccdpsf/trend/relations.h"
#include "ccdpsf/trend/requirements.h"

namespace ccdpsf::trend {

struct TrendOptions {
  double reference_intensity_e = kReferenceIntensityE;
  double reference_wavelength_nm = kReferenceWavelengthNm;
  // A wavelength's point for the power law must have |I / I0 - 1| <= this.
  double intensity_tolerance = 0.3;
  bool correct_to_reference_intensity = true;
  RelationOptions relation;
  std::vector<Requirement> requirements = DefaultRequirements();
  // The signal-dependent effect the intensity series were fitted with ("brighter_fatter",
  // "boundary_shift"; "" without series): names what the CCD-only intensity relations are.
  std::string intensity_series_effect;
};

struct TrendResult {
  std::vector<GroupResult> groups;
  // trend.json's "relations": <metric>_vs_wavelength and <metric>_vs_intensity (the latter at
  // intensity_wavelength_nm).
  std::map<std::string, RelationFit> relations;
  double intensity_wavelength_nm = NAN;
  // With an intensity series at intensity_wavelength_nm: the CCD-only <metric>_vs_intensity
  // relations of the intrinsic kernel (intensity_series.h), beside `relations`' affected ones.
  std::map<std::string, RelationFit> relations_intrinsic;
  std::string intensity_series_effect;  // TrendOptions::intensity_series_effect
  // Intensity relations at the other wavelengths with >= 2 settings: wavelength -> name -> fit.
  std::map<double, std::map<std::string, RelationFit>> intensity_by_wavelength;
  // The groups used for a wavelength relation of at least one metric, in wavelength order.
  std::vector<std::string> wavelength_groups;
  std::vector<RequirementResult> requirements;
  // Metric requirements at each fitted through-focus series' wavelength (within 0.5 nm),
  // judged on the series' own draws (EvaluateRequirementOnDraws; a note gives its intensity).
  struct FocusRequirement {
    std::string group;
    RequirementResult result;
  };
  std::vector<FocusRequirement> focus_requirements;
  std::vector<std::string> notes;  // what the reader should know (corrections, exclusions)
};

// False (with a one-line reason) only for invalid options.
bool ComputeTrend(std::vector<GroupResult> groups, const TrendOptions& options,
                  TrendResult* result, std::string* error);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_TREND_H_
