#include "ccdpsf/diagnose/statistics.h"

#include <algorithm>
#include <cmath>

#include "ccdpsf/chi_square.h"
#include "ccdpsf/fit/pixel_likelihood.h"
#include "ccdpsf/noise.h"
#include "ccdpsf/random.h"
#include "glog/logging.h"
#include "internal/parallel_for.h"

namespace ccdpsf::diagnose {

namespace {

constexpr int kRadialBins = 10;

struct Accumulator {
  double sum = 0.0;
  int count = 0;
  void Add(double r) {
    sum += r;
    ++count;
  }
  double Z() const { return count > 0 ? sum / std::sqrt(static_cast<double>(count)) : 0.0; }
};

}  // namespace

const std::vector<std::pair<std::string, std::string>>& StatisticDescriptions() {
  static const std::vector<std::pair<std::string, std::string>> d = {
      {"chi2_per_dof", "sum of squared normalised residuals per degree of freedom (every effect)"},
      {"core_z", "residual within 1.5 px of the centre (nonlinearity, ipc, brighter_fatter, halo)"},
      {"ring_z", "residual 1.5-4 px from the centre (halo, jitter, ipc)"},
      {"outer_z", "residual beyond 6 px: a pedestal (background, halo wing)"},
      {"odd_x_z", "odd moment along x, +x minus -x side (serial_cti)"},
      {"odd_y_z", "odd moment along y, +y minus -y side (parallel_cti)"},
      {"neighbour_z", "four edge neighbours of the peak minus four diagonal ones (ipc)"},
      {"peak_z", "residual of the peak pixel (nonlinearity, ipc)"},
      {"peak_trend_z",
       "core residual against peak signal across exposures (brighter_fatter, nonlinearity)"},
      {"width_scatter", "scatter of the exposures' width residuals (jitter, brighter_fatter)"},
      {"radial_chi2", "radial structure of the residual, 1-px annuli (halo, background, defocus)"},
  };
  return d;
}

const NamedStatistic* ResidualStatistics::Find(const std::string& name) const {
  for (const NamedStatistic& s : values) {
    if (s.name == name) return &s;
  }
  return nullptr;
}

std::vector<ExposureResidual> ComputeResiduals(const EffectModel& model,
                                               const std::vector<double>& p,
                                               const std::vector<Image>* data_e) {
  EffectEvaluator ev(model);
  std::vector<ExposureResidual> out;
  std::vector<double> m, c;
  for (int k = 0; k < model.num_exposures(); ++k) {
    const Stamp& s = model.base().stamps()[k];
    ExposureResidual e;
    e.data_e = data_e != nullptr ? (*data_e)[k] : s.electrons;
    e.model_e = Image(s.nx(), s.ny(), NAN);
    e.normalised = Image(s.nx(), s.ny(), NAN);
    // Residuals of measured pixels only: a censored pixel's value is a bound (the
    // likelihood takes it so), not a measurement a residual could be formed from.
    e.valid.assign(s.valid.size(), 0);
    for (size_t q = 0; q < s.valid.size(); ++q) e.valid[q] = s.Measured(q) ? 1 : 0;
    e.origin_x = s.origin_x;
    e.origin_y = s.origin_y;
    CHECK(ev.Render(p.data(), k, &m, &c)) << "ComputeResiduals outside the model's domain";
    const CcdNoise noise{s.gain_e_per_adu, s.read_noise_e};
    e.peak_e = *std::max_element(m.begin(), m.end());
    e.flux_e = 0.0;
    for (double v : m) e.flux_e += v;
    for (size_t q = 0; q < s.valid.size(); ++q) {
      e.model_e.data[q] = m[q];
      if (!e.valid[q]) continue;
      e.normalised.data[q] = (e.data_e.data[q] - m[q]) / std::sqrt(noise.VarianceE2(c[q]));
    }
    const model::SpotParams sp = model.fit_twin().SpotFor(model.TwinTheta(p.data()).data(), k);
    const model::PixelGrid grid = model.base().GridFor(k);
    e.centre_x = sp[model::kCentreX] - grid.x0;
    e.centre_y = sp[model::kCentreY] - grid.y0;
    out.push_back(std::move(e));
  }
  return out;
}

namespace {

// The intensity class of every exposure (statistics.h), classes numbered from the lowest.
std::vector<int> IntensityClasses(const std::vector<ExposureResidual>& residuals) {
  constexpr double kClassRatio = 1.25;
  std::vector<int> order(residuals.size());
  for (size_t k = 0; k < order.size(); ++k) order[k] = static_cast<int>(k);
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return residuals[a].flux_e < residuals[b].flux_e; });
  std::vector<int> cls(residuals.size(), 0);
  int current = 0;
  double lowest = residuals[order[0]].flux_e;
  for (int k : order) {
    if (residuals[k].flux_e > kClassRatio * lowest) {
      ++current;
      lowest = residuals[k].flux_e;
    }
    cls[k] = current;
  }
  return cls;
}

ResidualStack EmptyStack(int nx, int ny) {
  ResidualStack s;
  s.data = s.model = s.residual = s.normalised = s.count = Image(nx, ny, 0.0);
  return s;
}

// Adds pixel q of exposure e, normalised residual r, at stack pixel (si, sj).
void AddToStack(const ExposureResidual& e, size_t q, double r, int si, int sj, ResidualStack* s) {
  s->data(si, sj) += e.data_e.data[q];
  s->model(si, sj) += e.model_e.data[q];
  s->residual(si, sj) += e.data_e.data[q] - e.model_e.data[q];
  s->normalised(si, sj) += r;
  s->count(si, sj) += 1.0;
}

// A sum of n unit normals / sqrt(n) stays N(0, 1); pixels no exposure reached become NaN.
void FinishStack(ResidualStack* s) {
  for (size_t si = 0; si < s->count.data.size(); ++si) {
    if (s->count.data[si] == 0) {
      s->data.data[si] = s->model.data[si] = s->residual.data[si] = s->normalised.data[si] = NAN;
    } else {
      s->normalised.data[si] /= std::sqrt(s->count.data[si]);
    }
  }
}

}  // namespace

ResidualStatistics ComputeStatistics(const std::vector<ExposureResidual>& residuals,
                                     int num_parameters) {
  CHECK(!residuals.empty());
  ResidualStatistics st;
  const int nx = residuals[0].normalised.nx, ny = residuals[0].normalised.ny;
  const int kx = (nx - 1) / 2, ky = (ny - 1) / 2;
  st.stack = EmptyStack(nx, ny);
  const std::vector<int> intensity_class = IntensityClasses(residuals);
  st.by_intensity.resize(*std::max_element(intensity_class.begin(), intensity_class.end()) + 1);
  for (IntensityStack& c : st.by_intensity) {
    c.peak_min_e = INFINITY;
    c.peak_max_e = -INFINITY;
    c.stack = EmptyStack(nx, ny);
  }
  for (size_t k = 0; k < residuals.size(); ++k) {
    IntensityStack& c = st.by_intensity[intensity_class[k]];
    c.peak_min_e = std::min(c.peak_min_e, residuals[k].peak_e);
    c.peak_max_e = std::max(c.peak_max_e, residuals[k].peak_e);
    ++c.exposures;
  }
  Accumulator core, ring, outer, odd_x, odd_y;
  std::vector<Accumulator> radial(kRadialBins);
  double neighbour_sum = 0.0, peak_sum = 0.0;
  std::vector<double> widths;
  int num_pixels = 0;
  for (size_t k = 0; k < residuals.size(); ++k) {
    const ExposureResidual& e = residuals[k];
    IntensityStack& by_class = st.by_intensity[intensity_class[k]];
    const int px = static_cast<int>(std::lround(e.centre_x));
    const int py = static_cast<int>(std::lround(e.centre_y));
    Accumulator core_k;
    // Width residual: r projected on (rho^2 - mean rho^2) over rho < 4.
    std::vector<std::pair<double, double>> width_terms;
    for (int j = 0; j < e.normalised.ny; ++j) {
      for (int i = 0; i < e.normalised.nx; ++i) {
        const size_t q = static_cast<size_t>(j) * e.normalised.nx + i;
        if (!e.valid[q]) continue;
        const double r = e.normalised.data[q];
        ++num_pixels;
        st.chi2 += r * r;
        const double dx = i - e.centre_x, dy = j - e.centre_y;
        const double rho = std::hypot(dx, dy);
        if (rho < 1.5) {
          core.Add(r);
          core_k.Add(r);
        } else if (rho < 4.0) {
          ring.Add(r);
        } else if (rho >= 6.0) {
          outer.Add(r);
        }
        if (rho < 4.0) width_terms.push_back({rho * rho, r});
        if (std::fabs(dx) >= 0.5 && std::fabs(dx) <= 4.5 && std::fabs(dy) <= 4.5) {
          odd_x.Add(dx > 0 ? r : -r);
        }
        if (std::fabs(dy) >= 0.5 && std::fabs(dy) <= 4.5 && std::fabs(dx) <= 4.5) {
          odd_y.Add(dy > 0 ? r : -r);
        }
        const int bin = static_cast<int>(rho);
        if (bin < kRadialBins) radial[bin].Add(r);
        // The stack.
        const int si = i - px + kx, sj = j - py + ky;
        if (si < 0 || sj < 0 || si >= nx || sj >= ny) continue;
        AddToStack(e, q, r, si, sj, &st.stack);
        AddToStack(e, q, r, si, sj, &by_class.stack);
      }
    }
    // Neighbours of the peak pixel (the pixel nearest the centre).
    auto r_at = [&](int i, int j, double* out) {
      if (i < 0 || j < 0 || i >= e.normalised.nx || j >= e.normalised.ny) return false;
      const size_t q = static_cast<size_t>(j) * e.normalised.nx + i;
      if (!e.valid[q]) return false;
      *out = e.normalised.data[q];
      return true;
    };
    double edge = 0.0, diag = 0.0, v;
    int n_edge = 0, n_diag = 0;
    for (const auto& [di, dj] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
      if (r_at(px + di, py + dj, &v)) {
        edge += v;
        ++n_edge;
      }
    }
    for (const auto& [di, dj] : {std::pair{1, 1}, {-1, 1}, {1, -1}, {-1, -1}}) {
      if (r_at(px + di, py + dj, &v)) {
        diag += v;
        ++n_diag;
      }
    }
    if (n_edge > 0 && n_diag > 0) {
      neighbour_sum += (edge - diag) / std::sqrt(static_cast<double>(n_edge + n_diag));
    }
    if (r_at(px, py, &v)) peak_sum += v;
    st.peak_e.push_back(e.peak_e);
    st.flux_e.push_back(e.flux_e);
    st.core_z.push_back(core_k.Z());
    double mean_rho2 = 0.0;
    for (const auto& t : width_terms) mean_rho2 += t.first / width_terms.size();
    double proj = 0.0, norm = 0.0;
    for (const auto& t : width_terms) {
      proj += (t.first - mean_rho2) * t.second;
      norm += (t.first - mean_rho2) * (t.first - mean_rho2);
    }
    widths.push_back(norm > 0 ? proj / std::sqrt(norm) : 0.0);
  }
  const int num_exposures = static_cast<int>(residuals.size());
  st.dof = std::max(1, num_pixels - num_parameters);
  st.chi2_per_dof = st.chi2 / st.dof;
  st.chi2_per_dof_sd = std::sqrt(2.0 / st.dof);
  FinishStack(&st.stack);
  for (IntensityStack& c : st.by_intensity) FinishStack(&c.stack);
  double radial_chi2 = 0.0;
  for (const Accumulator& a : radial) {
    st.radial_mean.push_back(a.count > 0 ? a.sum / a.count : NAN);
    st.radial_count.push_back(a.count);
    if (a.count > 0) radial_chi2 += a.sum * a.sum / a.count;
  }
  // Peak trend across intensities.
  double trend = NAN;
  {
    const auto [lo, hi] = std::minmax_element(st.flux_e.begin(), st.flux_e.end());
    if (num_exposures >= 2 && *lo > 0 && *hi / *lo > 1.25) {
      double mean_i = 0.0;
      for (double i : st.flux_e) mean_i += i / num_exposures;
      double num = 0.0, den = 0.0;
      for (int k = 0; k < num_exposures; ++k) {
        num += st.core_z[k] * (st.flux_e[k] - mean_i);
        den += std::pow(st.flux_e[k] - mean_i, 2);
      }
      trend = num / std::sqrt(den);
    }
  }
  double width_scatter = NAN;
  if (num_exposures >= 2) {
    double mean_w = 0.0;
    for (double w : widths) mean_w += w / num_exposures;
    width_scatter = 0.0;
    for (double w : widths) width_scatter += (w - mean_w) * (w - mean_w);
  }
  const double k_norm = std::sqrt(static_cast<double>(num_exposures));
  st.values = {
      {"chi2_per_dof", st.chi2_per_dof, Tail::kUpper, NAN, "", NAN, NAN},
      {"core_z", core.Z(), Tail::kTwoSided, NAN, "", NAN, NAN},
      {"ring_z", ring.Z(), Tail::kTwoSided, NAN, "", NAN, NAN},
      {"outer_z", outer.Z(), Tail::kTwoSided, NAN, "", NAN, NAN},
      {"odd_x_z", odd_x.Z(), Tail::kTwoSided, NAN, "", NAN, NAN},
      {"odd_y_z", odd_y.Z(), Tail::kTwoSided, NAN, "", NAN, NAN},
      {"neighbour_z", neighbour_sum / k_norm, Tail::kTwoSided, NAN, "", NAN, NAN},
      {"peak_z", peak_sum / k_norm, Tail::kTwoSided, NAN, "", NAN, NAN},
      {"peak_trend_z", trend, Tail::kTwoSided, NAN, "", NAN, NAN},
      {"width_scatter", width_scatter, Tail::kUpper, NAN, "", NAN, NAN},
      {"radial_chi2", radial_chi2, Tail::kUpper, NAN, "", NAN, NAN},
  };
  return st;
}

// Simulations that must reach the observed value for the empirical p-value to stand.
constexpr int kMinBeyond = 5;

void PredictiveCheck(const EffectModel& model, const std::vector<double>& p,
                     const PredictiveOptions& options, ResidualStatistics* observed,
                     std::vector<std::vector<double>>* draws) {
  const int ns = static_cast<int>(observed->values.size());
  const int num = std::max(0, options.num_simulations);
  EffectFitOptions fit_options = options.fit;
  fit_options.num_threads = 1;
  // Only the refitted point is used, not its uncertainty; and 1e-8 of the cost moves the
  // statistics by far less than their spread across simulations.
  fit_options.laplace = false;
  fit_options.function_tolerance = std::max(fit_options.function_tolerance, 1e-8);
  // Simulation s uses its own engine and writes only its own row: any thread count gives
  // the same rows, gathered in simulation order below.
  std::vector<std::vector<double>> rows(num);
  auto simulate = [&](int s) {
    std::mt19937_64 engine(DeriveSeed(options.seed, static_cast<uint64_t>(s)));
    const std::vector<Image> data = SimulateData(model, p, engine);
    std::vector<double> at = p;
    rows[s].resize(ns, NAN);
    if (options.refit) {
      EffectFitResult refit;
      std::string error;
      // A failed refit leaves its row NaN (skipped below): statistics of an unfitted draw
      // would mix two reference distributions.
      if (!FitEffectModel(model, {p}, fit_options, &refit, &error, &data)) return;
      at = refit.p;
    }
    const ResidualStatistics sim = ComputeStatistics(ComputeResiduals(model, at, &data), model.dim());
    for (int i = 0; i < ns && i < static_cast<int>(sim.values.size()); ++i) {
      rows[s][i] = sim.values[i].value;
    }
  };
  internal::ParallelFor(num, options.threads, [&](int s, int) { simulate(s); });
  std::vector<std::vector<double>> values(ns);
  for (int s = 0; s < num; ++s) {
    for (int i = 0; i < ns; ++i) values[i].push_back(rows[s][i]);
  }
  for (int i = 0; i < ns; ++i) {
    NamedStatistic& o = observed->values[i];
    const std::vector<double>& v = values[i];
    if (!std::isfinite(o.value) || v.empty()) continue;
    int above = 0, below = 0, n = 0;
    double sum = 0.0, sum2 = 0.0;
    for (double x : v) {
      if (!std::isfinite(x)) continue;
      ++n;
      above += x >= o.value;
      below += x <= o.value;
      sum += x;
      sum2 += x * x;
    }
    if (n == 0) continue;
    const double upper = (1.0 + above) / (1.0 + n);
    const double lower = (1.0 + below) / (1.0 + n);
    o.p_value = o.tail == Tail::kUpper ? upper : std::min(1.0, 2.0 * std::min(upper, lower));
    o.p_method = "simulations";
    o.predictive_mean = sum / n;
    o.predictive_sd = n > 1 ? std::sqrt(std::max(0.0, (sum2 - sum * sum / n) / (n - 1))) : NAN;
    // Few simulations reach the observed value: the empirical p is at its floor 1 / (N + 1)
    // and says only "small". A normal tail through the simulations' mean and sd gives the
    // size of the misfit instead (an approximation; it is used only out in the tail).
    const int beyond = o.tail == Tail::kUpper ? above : std::min(above, below);
    if (beyond < kMinBeyond && std::isfinite(o.predictive_sd) && o.predictive_sd > 0) {
      const double z = (o.value - o.predictive_mean) / o.predictive_sd;
      const double tail = o.tail == Tail::kUpper ? std::exp(fit::LogNormalCdf(-z))
                                                 : 2.0 * std::exp(fit::LogNormalCdf(-std::fabs(z)));
      o.p_value = std::min(o.p_value, tail);
      o.p_method = "normal tail";
    }
  }
  // chi^2/dof has a known distribution: its p-value needs no simulation.
  for (NamedStatistic& o : observed->values) {
    if (o.name != "chi2_per_dof" || !(observed->dof >= 1) || !std::isfinite(o.value)) continue;
    o.p_value = ChiSquareUpperTail(o.value * observed->dof, observed->dof);
    o.p_method = "chi2 distribution";
  }
  if (draws != nullptr) *draws = std::move(values);
}

}  // namespace ccdpsf::diagnose
