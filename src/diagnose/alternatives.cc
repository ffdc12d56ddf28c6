#include "ccdpsf/diagnose/alternatives.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "glog/logging.h"

namespace ccdpsf::diagnose {

namespace {

// Response widths of the profile, widest first [px]: a window narrower than half the pixel
// would lose three quarters of flat light, far outside a scientific CCD.
constexpr double kResponseGrid[] = {0.9, 0.8, 0.7, 0.6, 0.5};

// Iteration cap of the pillbox solve (see FitPillbox).
constexpr int kPillboxIterations = 60;

// The Gaussian-defocus model's shape parameters at p.
struct Shape {
  double airy, defocus, sx, sy;
};
Shape ShapeOf(const EffectModel& m, const std::vector<double>& p) {
  return {p[m.ShapeIndex(fit::kAiryRadiusPx)], p[m.ShapeIndex(fit::kDefocusPx)],
          p[m.ShapeIndex(fit::kCcdSigmaXPx)], p[m.ShapeIndex(fit::kCcdSigmaYPx)]};
}

std::unique_ptr<fit::FitModel> WithOptions(const fit::FitModel& base,
                                           const model::ModelOptions& model_options,
                                           std::string* error) {
  fit::FitModelOptions o = base.options();
  o.model = model_options;
  return fit::FitModel::Create(base.stamps(), o, error);
}

// The pillbox: fit::FitModel's analytic-Jacobian solve from two starts, then the EffectModel
// of the same options scored (and its Laplace taken) at the result.
bool FitPillbox(const EffectModel& current, const EffectFitResult& current_fit,
                const EffectFitOptions& fit_options, const fit::MapOptions& map_options,
                AlternativeFit* out, std::string* error) {
  const fit::FitModel& base = current.base();
  model::ModelOptions mo = base.options().model;
  mo.defocus = model::DefocusKind::kPillbox;
  fit::FitModelOptions fo = base.options();
  fo.model = mo;
  fo.flux = current.spec().flux;
  auto solver_model = fit::FitModel::Create(base.stamps(), fo, error);
  if (!solver_model) return false;
  const std::vector<double>& p = current_fit.p;
  const Shape s = ShapeOf(current, p);
  // The solver's theta is the twin's without its effects, which come last in theta.
  std::vector<double> theta = current.TwinTheta(p.data());
  theta.resize(solver_model->dim());
  // Starts: the disc with the Gaussian's second moment (R^2 / 4 = sigma_f^2), and a disc of
  // 0.6 of that radius with the CCD widths taking the difference (a pillbox's flat top is
  // sharper-edged than a Gaussian, so the split can move either way).
  fit::MapResult best;
  bool any = false;
  std::string last_error;
  // Near R = 0 the pillbox's derivative in R vanishes (the disc changes the image at O(R^2)),
  // where a solve crawls: cap it (a converged pillbox fit takes ~10-20 iterations).
  fit::MapOptions mo_solve = map_options;
  mo_solve.max_iterations = std::min(map_options.max_iterations, kPillboxIterations);
  for (const double share : {1.0, 0.6}) {
    const double radius = std::max(2.0 * s.defocus * share, 0.1);
    const double extra = s.defocus * s.defocus - 0.25 * radius * radius;
    std::vector<double> start = theta;
    start[fit::kDefocusPx] = radius;
    start[fit::kCcdSigmaXPx] = std::sqrt(std::max(s.sx * s.sx + extra, 0.0025));
    start[fit::kCcdSigmaYPx] = std::sqrt(std::max(s.sy * s.sy + extra, 0.0025));
    fit::MapResult m;
    if (!fit::RefineMap(*solver_model, start, mo_solve, &m, &last_error)) continue;
    if (!any || m.log_likelihood > best.log_likelihood) best = m;
    any = true;
  }
  if (!any) {
    *error = "the pillbox fit failed: " + last_error;
    return false;
  }
  out->base = WithOptions(base, mo, error);
  if (!out->base) return false;
  out->model = EffectModel::Create(*out->base, current.spec(), error);
  if (!out->model) return false;
  std::vector<double> q = out->model->FromOther(current, p);
  for (int t = 0; t < solver_model->dim(); ++t) q[out->model->Index(t)] = best.theta[t];
  const int r = out->model->ShapeIndex(fit::kDefocusPx);
  // Scored at the solver's optimum. Only where the pillbox could be adopted (delta BIC below
  // kNonNestedDeltaBic) a few iterations of the EffectModel's own solve follow (the point is
  // already the optimum of the same likelihood), for its Laplace approximation.
  double log_l, chi2;
  if (!EffectEvaluator(*out->model).Score(q.data(), nullptr, &log_l, &chi2)) {
    *error = "the pillbox fit ended outside the model's domain";
    return false;
  }
  if (2.0 * (log_l - current_fit.log_likelihood) < -kNonNestedDeltaBic) {
    out->fit = EffectFitResult();
    out->fit.p = q;
    out->fit.log_likelihood = log_l;
    out->fit.chi2 = chi2;
    out->fit.num_pixels = out->model->NumValidPixels();
    out->fit.dof = out->fit.num_pixels - out->model->dim();
    out->fit.usable = true;
    out->parameter = "defocus_radius_px";
    out->value = q[r];
    return true;
  }
  EffectFitOptions polish = fit_options;
  polish.max_iterations = std::min(fit_options.max_iterations, 5);
  if (!FitEffectModel(*out->model, {q}, polish, &out->fit, error)) return false;
  out->parameter = "defocus_radius_px";
  out->value = out->fit.p[r];
  out->sd = out->fit.laplace.sd.empty() ? NAN : out->fit.laplace.sd[r];
  out->at_bound = std::find(out->fit.laplace.at_bound.begin(), out->fit.laplace.at_bound.end(),
                            r) != out->fit.laplace.at_bound.end();
  return true;
}

// One point of the response profile: the current spec with a window of width w, fitted from
// the current MAP with the flux and CCD widths moved to keep the spot's light and width.
bool FitResponseWidth(const EffectModel& current, const EffectFitResult& current_fit, double w,
                      const EffectFitOptions& fit_options, AlternativeFit* out,
                      std::string* error) {
  model::ModelOptions mo = current.base().options().model;
  mo.pixel_response_width = w;
  auto base = WithOptions(current.base(), mo, error);
  if (!base) return false;
  auto model = EffectModel::Create(*base, current.spec(), error);
  if (!model) return false;
  std::vector<double> q = model->FromOther(current, current_fit.p);
  // A window of width w collects about w^2 of the light of a spot that falls anywhere on
  // the pixel, and blurs with variance w^2 / 12 instead of 1 / 12.
  const double w_now = current.base().options().model.pixel_response_width;
  const double collected = (w * w) / (w_now * w_now);
  const int f = model->Index(fit::kFluxE);  // the flux ratios stay
  q[f] = std::clamp(q[f] / collected, model->lower()[f], model->upper()[f]);
  for (int axis : {fit::kCcdSigmaXPx, fit::kCcdSigmaYPx}) {
    const int i = model->ShapeIndex(axis);
    q[i] = std::clamp(std::sqrt(q[i] * q[i] + (w_now * w_now - w * w) / 12.0), model->lower()[i],
                      model->upper()[i]);
  }
  EffectFitResult fit;
  EffectFitOptions profile_options = fit_options;
  profile_options.laplace = false;  // only the best point's (FitResponse)
  if (!FitEffectModel(*model, {q}, profile_options, &fit, error)) return false;
  out->profile.push_back({w, fit.log_likelihood});
  if (!out->model || fit.log_likelihood > out->fit.log_likelihood) {
    out->base = std::move(base);
    out->model = std::move(model);
    out->fit = std::move(fit);
    out->value = w;
  }
  return true;
}

bool FitResponse(const EffectModel& current, const EffectFitResult& current_fit,
                 const EffectFitOptions& fit_options, AlternativeFit* out, std::string* error) {
  out->parameter = "pixel_response.width_px";
  const double w_now = current.base().options().model.pixel_response_width;
  out->profile.push_back({w_now, current_fit.log_likelihood});
  // Down the grid until the profile has fallen twice in a row past its best point.
  int falls = 0;
  double last = current_fit.log_likelihood;
  for (double w : kResponseGrid) {
    if (w >= w_now) continue;
    if (!FitResponseWidth(current, current_fit, w, fit_options, out, error)) return false;
    const double ll = out->profile.back().second;
    falls = ll < last ? falls + 1 : 0;
    last = ll;
    if (falls >= 2) break;
  }
  if (!out->model) {
    *error = "no narrower pixel response to try";
    return false;
  }
  // The parabola through the best grid point and its neighbours (the profile is sorted by
  // decreasing w): its vertex, fitted if it lies between them, and the curvature gives sd.
  std::vector<std::pair<double, double>> pr = out->profile;
  std::sort(pr.begin(), pr.end());
  size_t b = 0;
  for (size_t i = 1; i < pr.size(); ++i) {
    if (pr[i].second > pr[b].second) b = i;
  }
  if (b == 0) out->at_bound = true;  // the narrowest window tried
  if (b > 0 && b + 1 < pr.size()) {
    const double x0 = pr[b - 1].first, x1 = pr[b].first, x2 = pr[b + 1].first;
    const double y0 = pr[b - 1].second, y1 = pr[b].second, y2 = pr[b + 1].second;
    // Divided differences: y = y1 + d1 (x - x1) + a (x - x1)(x - x0)... written directly.
    const double d01 = (y1 - y0) / (x1 - x0), d12 = (y2 - y1) / (x2 - x1);
    const double a = (d12 - d01) / (x2 - x0);  // quadratic coefficient
    if (a < 0) {
      const double vertex = 0.5 * (x0 + x1) - d01 / (2 * a);
      out->sd = 1.0 / std::sqrt(-2.0 * a);
      if (vertex > x0 && vertex < x2 && std::abs(vertex - x1) > 0.005 && vertex < w_now) {
        std::string ignored;
        FitResponseWidth(current, current_fit, vertex, fit_options, out, &ignored);
      }
    }
  }
  return !fit_options.laplace || AddLaplace(*out->model, &out->fit, error);
}

}  // namespace

std::string ToString(AlternativeKind kind) {
  switch (kind) {
    case AlternativeKind::kPillboxDefocus: return "pillbox_defocus";
    case AlternativeKind::kPixelResponse: return "pixel_response";
  }
  return "";
}

const std::vector<AlternativeKind>& AllAlternatives() {
  static const std::vector<AlternativeKind> all = {AlternativeKind::kPillboxDefocus,
                                                   AlternativeKind::kPixelResponse};
  return all;
}

std::string AlternativeNotApplicable(const EffectModel& current, AlternativeKind kind) {
  const model::ModelOptions& mo = current.base().options().model;
  if (mo.sampling != model::Sampling::kIntegrated) {
    return "the 2015 pixel_centre model has neither a pillbox nor a pixel response";
  }
  switch (kind) {
    case AlternativeKind::kPillboxDefocus:
      if (mo.defocus == model::DefocusKind::kPillbox) return "the model's defocus is a pillbox";
      if (!current.spec().defocus) return "the model has no defocus";
      if (!current.spec().effects.empty()) {
        return "tried only on a model without added effects (the pillbox is fitted with the "
               "analytic-Jacobian model, which has none)";
      }
      return "";
    case AlternativeKind::kPixelResponse:
      if (mo.pixel_response_width < 1.0) {
        return "the model's pixel response is already narrower than the pixel";
      }
      if (current.spec().Has(model::EffectKind::kBoundaryShift)) {
        return "the model has boundary_shift, whose boundaries move in the integral over the "
               "whole pixel (a narrower collecting window would need its own boundary physics)";
      }
      return "";
  }
  return "";
}

bool FitAlternative(const EffectModel& current, const EffectFitResult& current_fit,
                    AlternativeKind kind, const EffectFitOptions& fit_options,
                    const fit::MapOptions& map_options, AlternativeFit* out, std::string* error) {
  *out = AlternativeFit();
  out->kind = kind;
  const std::string why = AlternativeNotApplicable(current, kind);
  if (!why.empty()) {
    *error = why;
    return false;
  }
  return kind == AlternativeKind::kPillboxDefocus
             ? FitPillbox(current, current_fit, fit_options, map_options, out, error)
             : FitResponse(current, current_fit, fit_options, out, error);
}

std::string DescribeModelOptions(const model::ModelOptions& options) {
  std::string out;
  if (options.defocus == model::DefocusKind::kPillbox) out = "pillbox defocus";
  if (options.pixel_response_width < 1.0) {
    char buf[64];
    std::snprintf(buf, sizeof(buf), "pixel response %.2f px", options.pixel_response_width);
    out += (out.empty() ? "" : ", ") + std::string(buf);
  }
  return out;
}

}  // namespace ccdpsf::diagnose
