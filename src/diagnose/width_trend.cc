#include "ccdpsf/diagnose/width_trend.h"

#include <algorithm>
#include <cmath>

#include "ccdpsf/diagnose/statistics.h"

namespace ccdpsf::diagnose {

namespace {

// Peak signals must span this factor for a slope to mean something (as IsMultiIntensity).
constexpr double kMinPeakSpan = 1.25;

// The total Gaussian width of the current model along one axis [px].
double TotalWidth(const EffectModel& m, const std::vector<double>& p, int axis) {
  const double s = p[m.ShapeIndex(axis)];
  if (!m.spec().defocus) return s;
  const double f = p[m.ShapeIndex(fit::kDefocusPx)];
  return m.base().options().model.defocus == model::DefocusKind::kPillbox
             ? std::sqrt(s * s + 0.25 * f * f)
             : std::hypot(s, f);
}

// Weighted least squares of y = a + b x; false when fewer than 2 usable points.
bool FitLine(const std::vector<double>& x, const std::vector<double>& y,
             const std::vector<double>& sd, WidthLine* line) {
  double sw = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
  int n = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    if (!(std::isfinite(x[i]) && std::isfinite(y[i]) && sd[i] > 0)) continue;
    const double w = 1.0 / (sd[i] * sd[i]);
    sw += w;
    sx += w * x[i];
    sy += w * y[i];
    sxx += w * x[i] * x[i];
    sxy += w * x[i] * y[i];
    ++n;
  }
  const double det = sw * sxx - sx * sx;
  if (n < 2 || !(det > 0)) return false;
  const double b = (sw * sxy - sx * sy) / det;
  const double a = (sy - b * sx) / sw;
  double chi2 = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    if (!(std::isfinite(x[i]) && std::isfinite(y[i]) && sd[i] > 0)) continue;
    const double r = (y[i] - a - b * x[i]) / sd[i];
    chi2 += r * r;
  }
  line->dof = n - 2;
  line->chi2 = chi2;
  const double inflate = line->dof > 0 ? std::sqrt(std::max(1.0, chi2 / line->dof)) : 1.0;
  line->sigma0_px = a;
  line->sigma0_sd = std::sqrt(sxx / det) * inflate;
  line->slope_px_per_e = b;
  line->slope_sd = std::sqrt(sw / det) * inflate;
  line->percent_per_1e5_e = 100.0 * b * 1e5 / a;
  line->percent_sd = 100.0 * line->slope_sd * 1e5 / a;
  return true;
}

}  // namespace

WidthTrend MeasureWidthTrend(const EffectModel& current, const EffectFitResult& current_fit,
                             const EffectFitOptions& fit_options) {
  WidthTrend out;
  const fit::FitModel& base = current.base();
  const std::vector<double>& p = current_fit.p;
  const int n = current.num_exposures();
  if (n < 2) {
    out.note = "one exposure: no trend to measure";
    return out;
  }
  fit::FitModelOptions o = base.options();
  o.flux = fit::FluxMode::kShared;
  o.model.defocus = model::DefocusKind::kGaussian;
  ModelSpec spec;
  spec.defocus = false;
  spec.flux = FluxMode::kShared;
  for (int k = 0; k < n; ++k) {
    std::string error;
    auto single = fit::FitModel::Create({base.stamps()[k]}, o, &error);
    if (!single) continue;
    auto m = EffectModel::Create(*single, spec, &error);
    if (!m) continue;
    std::vector<double> q(m->dim(), 0.0);
    q[m->Index(fit::kFluxE)] = current.FluxOf(p, k);
    q[m->ShapeIndex(fit::kAiryRadiusPx)] = p[current.ShapeIndex(fit::kAiryRadiusPx)];
    for (int axis : {fit::kCcdSigmaXPx, fit::kCcdSigmaYPx}) {
      q[m->ShapeIndex(axis)] = TotalWidth(current, p, axis);
    }
    q[m->XIndex(0)] = p[current.XIndex(k)];
    q[m->YIndex(0)] = p[current.YIndex(k)];
    EffectFitResult fit;
    if (!FitEffectModel(*m, {q}, fit_options, &fit, &error)) continue;
    WidthPoint w;
    w.exposure = k;
    w.peak_e = ComputeResiduals(*m, fit.p)[0].peak_e;
    for (int a = 0; a < 2; ++a) {
      const int i = m->ShapeIndex(a == 0 ? fit::kCcdSigmaXPx : fit::kCcdSigmaYPx);
      w.sigma_px[a] = fit.p[i];
      w.sd_px[a] = fit.laplace.sd.empty() ? NAN : fit.laplace.sd[i];
    }
    out.points.push_back(w);
  }
  double lo = INFINITY, hi = 0;
  for (const WidthPoint& w : out.points) {
    lo = std::min(lo, w.peak_e);
    hi = std::max(hi, w.peak_e);
  }
  if (out.points.size() < 2 || !(hi >= kMinPeakSpan * lo)) {
    out.note = out.points.size() < 2 ? "fewer than two exposures could be fitted alone"
                                     : "the peak signals span less than a factor 1.25";
    return out;
  }
  std::vector<double> x;
  for (const WidthPoint& w : out.points) x.push_back(w.peak_e);
  for (int a = 0; a < 2; ++a) {
    std::vector<double> y, sd;
    for (const WidthPoint& w : out.points) {
      y.push_back(w.sigma_px[a]);
      sd.push_back(w.sd_px[a]);
    }
    if (!FitLine(x, y, sd, &out.axis[a])) {
      out.note = "the per-exposure widths have no usable uncertainties";
      return out;
    }
  }
  out.measured = true;
  return out;
}

double TotalWidthSlope(double ccd_slope, double sigma_ccd, double defocus,
                       model::DefocusKind kind) {
  const double total = kind == model::DefocusKind::kPillbox
                           ? std::sqrt(sigma_ccd * sigma_ccd + 0.25 * defocus * defocus)
                           : std::hypot(sigma_ccd, defocus);
  return total > 0 ? ccd_slope * sigma_ccd / total : NAN;
}

}  // namespace ccdpsf::diagnose
