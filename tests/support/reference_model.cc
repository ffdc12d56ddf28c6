// Fourier-space reference for the pixel-integrated spot model. See reference_model.h for the
// formula; this file only holds the quadrature.
#include "support/reference_model.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <vector>

#include "glog/logging.h"

namespace ccdpsf::testing_reference {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Gauss-Legendre nodes per panel. 16 nodes resolve two cycles of a cosine per panel to
// ~1e-19 relative (the Bernstein-ellipse bound (e w / 4 n)^(2 n) with w = 2 pi, n = 16).
constexpr int kOrder = 16;

// The radial range is cut where the Gaussian envelope's integral over the rest of the plane,
// (pi / a) exp(-a rho^2), falls below this fraction of the flux: far below the tolerances.
constexpr double kEnvelopeTail = 1e-17;

struct Rule {
  std::vector<double> x;  // nodes on [-1, 1]
  std::vector<double> w;
};

const Rule& PanelRule() {
  static const Rule rule = [] {
    Rule r;
    GaussLegendre(kOrder, &r.x, &r.w);
    return r;
  }();
  return rule;
}

// sin(pi u) / (pi u). The Taylor series below |pi u| = 1e-3 has error < 1e-21.
double Sinc(double u) {
  const double z = kPi * u;
  if (std::abs(z) < 1e-3) {
    const double z2 = z * z;
    return 1.0 - z2 / 6.0 + z2 * z2 / 120.0;
  }
  return std::sin(z) / z;
}

// 2 J1(z) / z, with its Taylor series near 0 (error < z^6 / 9216 < 1e-22 there). glibc's
// POSIX j0/j1 are used rather than std::cyl_bessel_j: ~1e-17 absolute error against mpmath
// on [0, 100] where libstdc++'s reaches 6e-15, and 15 times faster.
double Jinc(double z) {
  if (std::abs(z) < 1e-3) {
    const double z2 = z * z;
    return 1.0 - z2 / 8.0 + z2 * z2 / 192.0;
  }
  return 2.0 * ::j1(z) / z;
}

// The circular-pupil OTF at s = 1 - t^2, written so that it is analytic in t and exact near
// the disc edge (t -> 0), where acos(1 - t^2) would lose digits.
double OtfOfT(double t) {
  const double acos_s = 2.0 * std::asin(t / std::sqrt(2.0));
  const double s_sqrt = (1.0 - t * t) * t * std::sqrt(2.0 - t * t);
  return (2.0 / kPi) * (acos_s - s_sqrt);
}

// Transform of the unit-integral defocus kernel at radial frequency rho [cycles/px].
double DefocusTransform(const ReferenceSpot& spot, double rho) {
  if (spot.defocus_px == 0.0) return 1.0;
  if (spot.defocus_kind == model::DefocusKind::kGaussian) {
    const double s = spot.defocus_px;
    return std::exp(-2.0 * kPi * kPi * s * s * rho * rho);
  }
  return Jinc(2.0 * kPi * spot.defocus_px * rho);
}

// Angular rule on [0, pi / 2] with `panels` Gauss-Legendre panels: cos, sin and weight per
// node. Cached by panel count, since the count varies with the radius.
struct AngularRule {
  std::vector<double> c, s, w;
};

class AngularRules {
 public:
  const AngularRule& Get(int panels) {
    auto it = rules_.find(panels);
    if (it != rules_.end()) return it->second;
    const Rule& base = PanelRule();
    AngularRule rule;
    const double h = 0.5 * kPi / panels;
    for (int p = 0; p < panels; ++p) {
      const double mid = (p + 0.5) * h;
      for (int k = 0; k < kOrder; ++k) {
        const double theta = mid + 0.5 * h * base.x[k];
        rule.c.push_back(std::cos(theta));
        rule.s.push_back(std::sin(theta));
        rule.w.push_back(0.5 * h * base.w[k]);
      }
    }
    return rules_.emplace(panels, std::move(rule)).first->second;
  }

 private:
  std::map<int, AngularRule> rules_;
};

// The geometry of one integration, fixed across levels.
struct Plan {
  bool airy = true;
  double rho_c = 0.0;  // Airy cutoff [cycles/px]
  double var_lo = 0.0;  // radial variable range: t for the Airy, rho for a point source
  double var_hi = 0.0;
  int radial_panels0 = 2;      // level-0 radial panel count
  double angular_cycles = 0.0;  // oscillations over the quadrant per unit rho
};

Plan MakePlan(const ReferenceSpot& spot, double max_abs_dx, double max_abs_dy) {
  Plan plan;
  plan.airy = spot.pupil == Pupil::kAiry;
  const double sigma_min = std::min(spot.ccd_sigma_x_px, spot.ccd_sigma_y_px);
  const double sigma_f =
      spot.defocus_kind == model::DefocusKind::kGaussian ? spot.defocus_px : 0.0;
  // |integrand| <= exp(-a rho^2): OTF, pillbox transform, sincs and cosines are all <= 1.
  const double a = 2.0 * kPi * kPi * (sigma_min * sigma_min + sigma_f * sigma_f);
  double rho_cut = std::numeric_limits<double>::infinity();
  if (a > 0.0) rho_cut = std::sqrt(std::max(0.0, std::log(kPi / (a * kEnvelopeTail))) / a);

  // Oscillations per unit rho of the integrand: the cosines (|dx| + |dy|), the sincs
  // (1/2 each) and the pillbox transform (R, ~ two zeros of J1 per 2 pi R rho = 2 pi).
  const double pillbox_r =
      spot.defocus_kind == model::DefocusKind::kPillbox ? spot.defocus_px : 0.0;
  const double radial_frequency = max_abs_dx + max_abs_dy + 1.0 + pillbox_r;
  plan.angular_cycles = max_abs_dx + max_abs_dy + 1.0;

  double radial_cycles = 0.0;
  if (plan.airy) {
    plan.rho_c = model::kAiryRz / spot.airy_radius_px;
    const double rho_hi = std::min(plan.rho_c, rho_cut);
    plan.var_lo = std::sqrt(std::max(0.0, 1.0 - rho_hi / plan.rho_c));
    plan.var_hi = 1.0;
    // rho = rho_c (1 - t^2): the oscillation density in t peaks at |d rho / d t| = 2 rho_c.
    radial_cycles = radial_frequency * 2.0 * plan.rho_c * (plan.var_hi - plan.var_lo);
  } else {
    CHECK(std::isfinite(rho_cut)) << "a point source needs a Gaussian width > 0";
    plan.var_lo = 0.0;
    plan.var_hi = rho_cut;
    radial_cycles = radial_frequency * rho_cut;
  }
  // Two cycles per 16-node panel at level 0.
  plan.radial_panels0 = std::max(2, static_cast<int>(std::ceil(radial_cycles / 2.0)));
  return plan;
}

// Calls accumulate(weight, u, v) for every node of the level-`level` rule, where `weight`
// already holds the quadrature weight times everything in the integrand except the
// pixel-dependent cosines, including the factor 4 for the four quadrants (unit flux).
template <typename Accumulate>
long long Sweep(const ReferenceSpot& spot, const Plan& plan, int level, AngularRules* rules,
                Accumulate&& accumulate) {
  const Rule& base = PanelRule();
  const int radial_panels = plan.radial_panels0 << level;
  const double h = (plan.var_hi - plan.var_lo) / radial_panels;
  const double a_x = 2.0 * kPi * kPi * spot.ccd_sigma_x_px * spot.ccd_sigma_x_px;
  const double a_y = 2.0 * kPi * kPi * spot.ccd_sigma_y_px * spot.ccd_sigma_y_px;
  long long nodes = 0;
  for (int p = 0; p < radial_panels; ++p) {
    const double mid = plan.var_lo + (p + 0.5) * h;
    for (int k = 0; k < kOrder; ++k) {
      const double var = mid + 0.5 * h * base.x[k];
      double rho, radial_weight;
      if (plan.airy) {
        const double t = var;
        rho = plan.rho_c * (1.0 - t * t);
        // rho d rho = rho * 2 rho_c t dt.
        radial_weight = 0.5 * h * base.w[k] * rho * 2.0 * plan.rho_c * t * OtfOfT(t);
      } else {
        rho = var;
        radial_weight = 0.5 * h * base.w[k] * rho;
      }
      radial_weight *= 4.0 * DefocusTransform(spot, rho);
      if (radial_weight == 0.0) continue;
      const int angular_panels =
          std::max(2, static_cast<int>(std::ceil(rho * plan.angular_cycles / 2.0))) << level;
      const AngularRule& ang = rules->Get(angular_panels);
      const int n = static_cast<int>(ang.w.size());
      for (int q = 0; q < n; ++q) {
        const double u = rho * ang.c[q];
        const double v = rho * ang.s[q];
        const double wx = spot.pixel_window_x > 0.0 ? spot.pixel_window_x : spot.pixel_window;
        const double wy = spot.pixel_window_y > 0.0 ? spot.pixel_window_y : spot.pixel_window;
        // A line along an axis has the transform 1 there (ReferenceSpot::line_x).
        const double box_u = spot.line_x ? 1.0 : wx * Sinc(wx * u);
        const double box_v = spot.line_y ? 1.0 : wy * Sinc(wy * v);
        const double g = std::exp(-(a_x * u * u + a_y * v * v)) * box_u * box_v;
        accumulate(radial_weight * ang.w[q] * g, u, v);
      }
      nodes += n;
    }
  }
  return nodes;
}

}  // namespace

void GaussLegendre(int n, std::vector<double>* nodes, std::vector<double>* weights) {
  CHECK_GE(n, 1);
  nodes->assign(n, 0.0);
  weights->assign(n, 0.0);
  for (int i = 0; i < (n + 1) / 2; ++i) {
    // Tricomi's first-order estimate of the i-th largest root.
    double z = std::cos(kPi * (i + 0.75) / (n + 0.5));
    double derivative = 0.0;
    for (int iteration = 0; iteration < 100; ++iteration) {
      // P_n(z) and P_{n-1}(z) by (k) P_k = (2k - 1) z P_{k-1} - (k - 1) P_{k-2}.
      double p_prev = 1.0;
      double p = z;
      for (int k = 2; k <= n; ++k) {
        const double p_next = ((2.0 * k - 1.0) * z * p - (k - 1.0) * p_prev) / k;
        p_prev = p;
        p = p_next;
      }
      // (z^2 - 1) P_n' = n (z P_n - P_{n-1}).
      derivative = n * (z * p - p_prev) / (z * z - 1.0);
      const double step = p / derivative;
      z -= step;
      if (std::abs(step) < 1e-16) {
        // One more pass for the derivative at the converged root.
        p_prev = 1.0;
        p = z;
        for (int k = 2; k <= n; ++k) {
          const double p_next = ((2.0 * k - 1.0) * z * p - (k - 1.0) * p_prev) / k;
          p_prev = p;
          p = p_next;
        }
        derivative = n * (z * p - p_prev) / (z * z - 1.0);
        break;
      }
    }
    const double w = 2.0 / ((1.0 - z * z) * derivative * derivative);
    (*nodes)[i] = -z;
    (*nodes)[n - 1 - i] = z;
    (*weights)[i] = w;
    (*weights)[n - 1 - i] = w;
  }
  if (n % 2 == 1) (*nodes)[n / 2] = 0.0;
}

double GaussianIntervalProbability(double a, double b, double sigma) {
  CHECK_GT(sigma, 0.0);
  CHECK_LE(a, b);
  const double scale = 1.0 / (sigma * std::sqrt(2.0));
  const double za = a * scale;
  const double zb = b * scale;
  if (za >= 0.0) return 0.5 * (std::erfc(za) - std::erfc(zb));
  if (zb <= 0.0) return 0.5 * (std::erfc(-zb) - std::erfc(-za));
  return 0.5 * (std::erf(zb) - std::erf(za));
}

double PixelIntegratedGaussian(double flux, double dx, double dy, double sigma_x,
                               double sigma_y) {
  return flux * GaussianIntervalProbability(dx - 0.5, dx + 0.5, sigma_x) *
         GaussianIntervalProbability(dy - 0.5, dy + 0.5, sigma_y);
}

double AiryIntensity(double d_px, double airy_radius_px) {
  const double k = kPi * model::kAiryRz / airy_radius_px;
  const double f = Jinc(k * d_px);
  return k * k / (4.0 * kPi) * f * f;
}

double AiryEnergyOutside(double d_px, double airy_radius_px) {
  const double x = kPi * model::kAiryRz / airy_radius_px * d_px;
  const double j0 = ::j0(x);
  const double j1 = ::j1(x);
  return j0 * j0 + j1 * j1;
}

ReferenceSpot FromSpotParams(const model::SpotParams& params, model::DefocusKind kind) {
  ReferenceSpot spot;
  spot.flux_e = params[model::kFlux];
  spot.centre_x_px = params[model::kCentreX];
  spot.centre_y_px = params[model::kCentreY];
  spot.pupil = Pupil::kAiry;
  spot.airy_radius_px = params[model::kAiryRadius];
  spot.defocus_kind = kind;
  spot.defocus_px = params[model::kDefocus];
  spot.ccd_sigma_x_px = params[model::kCcdSigmaX];
  spot.ccd_sigma_y_px = params[model::kCcdSigmaY];
  return spot;
}

ReferenceResult ReferenceImage(const ReferenceSpot& spot, int nx, int ny, double x0, double y0,
                               double tolerance) {
  CHECK_GE(nx, 1);
  CHECK_GE(ny, 1);
  CHECK(spot.pupil == Pupil::kPointSource || spot.airy_radius_px > 0.0);
  CHECK_GE(spot.defocus_px, 0.0);
  CHECK_GE(spot.ccd_sigma_x_px, 0.0);
  CHECK_GE(spot.ccd_sigma_y_px, 0.0);

  // Offsets of the first pixel centre from the spot centre, and the largest |offset|.
  const double dx0 = x0 - spot.centre_x_px;
  const double dy0 = y0 - spot.centre_y_px;
  const double max_dx = std::max(std::abs(dx0), std::abs(dx0 + nx - 1));
  const double max_dy = std::max(std::abs(dy0), std::abs(dy0 + ny - 1));
  const Plan plan = MakePlan(spot, max_dx, max_dy);
  AngularRules rules;

  ReferenceResult result;
  std::vector<double> previous;
  std::vector<double> current(static_cast<size_t>(nx) * ny);
  std::vector<double> cos_x(nx), cos_y(ny);

  // cos(2 pi w (d0 + i)) for i = 0 .. n-1 by rotating (cos, sin) by 2 pi w at each step;
  // the rounding error grows linearly, to ~n eps for the <= 41 pixels per row used here.
  auto fill_cosines = [](double w, double d0, std::vector<double>* out) {
    const double phase = 2.0 * kPi * w;
    double c = std::cos(phase * d0);
    double s = std::sin(phase * d0);
    const double cs = std::cos(phase);
    const double sn = std::sin(phase);
    for (double& value : *out) {
      value = c;
      const double c_next = c * cs - s * sn;
      s = s * cs + c * sn;
      c = c_next;
    }
  };

  for (int level = 0; level <= kMaxLevels; ++level) {
    std::fill(current.begin(), current.end(), 0.0);
    if (nx == 1 && ny == 1) {
      double sum = 0.0;
      result.nodes += Sweep(spot, plan, level, &rules, [&](double weight, double u, double v) {
        sum += weight * std::cos(2.0 * kPi * u * dx0) * std::cos(2.0 * kPi * v * dy0);
      });
      current[0] = sum;
    } else {
      result.nodes += Sweep(spot, plan, level, &rules, [&](double weight, double u, double v) {
        fill_cosines(u, dx0, &cos_x);
        fill_cosines(v, dy0, &cos_y);
        for (int j = 0; j < ny; ++j) {
          const double wy = weight * cos_y[j];
          double* row = current.data() + static_cast<size_t>(j) * nx;
          for (int i = 0; i < nx; ++i) row[i] += wy * cos_x[i];
        }
      });
    }
    result.levels = level;
    if (level > 0) {
      double change = 0.0;
      for (size_t p = 0; p < current.size(); ++p) {
        change = std::max(change, std::abs(current[p] - previous[p]));
      }
      result.last_change = change * spot.flux_e;
      if (change <= tolerance) {
        result.converged = true;
        break;
      }
    }
    previous = current;
  }
  result.values.resize(current.size());
  for (size_t p = 0; p < current.size(); ++p) result.values[p] = spot.flux_e * current[p];
  if (!result.converged) {
    LOG(ERROR) << "Reference model did not converge after " << kMaxLevels
               << " doublings: last change " << result.last_change << " e- (flux "
               << spot.flux_e << ")";
  }
  return result;
}

ReferenceResult ReferencePixel(const ReferenceSpot& spot, double x_px, double y_px,
                               double tolerance) {
  return ReferenceImage(spot, 1, 1, x_px, y_px, tolerance);
}

}  // namespace ccdpsf::testing_reference
