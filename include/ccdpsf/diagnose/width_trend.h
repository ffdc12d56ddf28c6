// The spot's width against its signal, measured exposure by exposure: the model-light check
// of brighter-fatter in `ccdpsf diagnose`.
//
// Each exposure is fitted alone with the paper's spot without a separate defocus (Airy
// convolved with one Gaussian of widths sigma_x, sigma_y per axis: with a Gaussian defocus
// only sigma_f^2 + sigma_ccd^2 is identified, docs/trust.md, single focus, so this is the total
// width), its own flux, position and Airy radius. The total widths are then regressed on the
// exposure's peak signal I (the fitted model's largest pixel [e-], the quantity the
// catalogue's brighter_fatter slope multiplies) by weighted least squares, weights 1 / sd^2
// from each fit's Laplace sd:
//
//   sigma_tot(I) = sigma_0 + slope I        [px, px per e-]
//
// The slope's sd is the least-squares one, multiplied by sqrt(chi2 / dof) of the line when the
// widths scatter more than their errors (so an exposure-to-exposure change that is not a trend
// widens the interval instead of faking precision). Also in the units a detector scientist
// quotes: the percentage growth of the width per 10^5 e- of peak signal,
// 100 slope 1e5 / sigma_0.
//
// Brighter-fatter makes the slope positive; nonlinearity flattens the core (peak pixel
// compressed) with much less change of the width measured on the whole profile; a flux-
// independent change (jitter) adds scatter without a slope.
#ifndef CCDPSF_DIAGNOSE_WIDTH_TREND_H_
#define CCDPSF_DIAGNOSE_WIDTH_TREND_H_

#include <string>
#include <vector>

#include "ccdpsf/diagnose/effect_fit.h"

namespace ccdpsf::diagnose {

struct WidthPoint {
  int exposure = 0;
  double peak_e = NAN;  // the fit's largest model pixel [e-]
  double sigma_px[2] = {NAN, NAN};  // total width along x, y [px]
  double sd_px[2] = {NAN, NAN};
};

struct WidthLine {
  double sigma0_px = NAN, sigma0_sd = NAN;  // at zero signal
  double slope_px_per_e = NAN, slope_sd = NAN;
  double percent_per_1e5_e = NAN, percent_sd = NAN;
  double chi2 = NAN;  // of the points about the line
  int dof = 0;
};

struct WidthTrend {
  bool measured = false;
  std::string note;  // why not, when not measured
  std::vector<WidthPoint> points;
  WidthLine axis[2];  // x, y
};

// Measures the trend on the stamps of `current`, each fit started from the joint MAP
// `current_fit` (its positions, fluxes, Airy radius and total widths). Needs two or more
// exposures whose peak signals differ by a factor 1.25 or more; otherwise `measured` is false
// with a note.
WidthTrend MeasureWidthTrend(const EffectModel& current, const EffectFitResult& current_fit,
                             const EffectFitOptions& fit_options);

// The slope of the TOTAL width implied by a brighter_fatter slope of the CCD width, at zero
// signal: d sigma_tot / dI = slope sigma_ccd / sigma_tot (sigma_tot^2 = sigma_ccd^2 +
// sigma_f^2 for a Gaussian defocus, + R^2 / 4 for a pillbox).
double TotalWidthSlope(double ccd_slope, double sigma_ccd, double defocus,
                       model::DefocusKind kind);

}  // namespace ccdpsf::diagnose

#endif  // CCDPSF_DIAGNOSE_WIDTH_TREND_H_
