#include "ccdpsf/fit/autocorrelation.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace ccdpsf::fit {
namespace {

// Radix-2 FFT of a power-of-two length n on separate real and imaginary arrays (so the
// butterfly loops vectorise), in two halves that together skip the bit-reversal permutation
// (a cache-missing shuffle that took a quarter of the time of a 2^16-point transform):
//   Forward: decimation in frequency, natural-order input -> bit-reversed output,
//            X_k = sum_j x_j exp(-2 pi i j k / n);
//   Inverse: decimation in time, bit-reversed input -> natural-order output,
//            x_j = sum_k X_k exp(+2 pi i j k / n)   (unscaled: n times the true inverse).
// Between the two, only element-wise operations are allowed (order does not matter to them).
class Fft {
 public:
  explicit Fft(size_t n) : n_(n), cos_(n > 1 ? n - 1 : 0), sin_(n > 1 ? n - 1 : 0) {
    // The stage of butterfly half-length h uses w_h^m = exp(-i pi m / h), m < h; the tables
    // of all stages are stored one after another (h = 1, 2, 4, ... at offset h - 1), each
    // computed directly rather than by recurrence so that rounding does not accumulate.
    for (size_t h = 1; h < n_; h <<= 1) {
      for (size_t m = 0; m < h; ++m) {
        const double angle = -M_PI * static_cast<double>(m) / static_cast<double>(h);
        cos_[h - 1 + m] = std::cos(angle);
        sin_[h - 1 + m] = std::sin(angle);
      }
    }
  }

  void Forward(double* re, double* im) const {
    for (size_t h = n_ >> 1; h >= 1; h >>= 1) ForwardStage(re, im, h);
  }

  void Inverse(double* re, double* im) const {
    for (size_t h = 1; h < n_; h <<= 1) InverseStage(re, im, h);
  }

 private:
  // One pass over all n points with butterflies of half-length h.
  void ForwardStage(double* re, double* im, size_t h) const {
    const double* wr = &cos_[h - 1];
    const double* wi = &sin_[h - 1];
    for (size_t start = 0; start < n_; start += 2 * h) {
      double* lo_re = re + start;
      double* lo_im = im + start;
      double* hi_re = re + start + h;
      double* hi_im = im + start + h;
      for (size_t m = 0; m < h; ++m) {
        const double dr = lo_re[m] - hi_re[m];
        const double di = lo_im[m] - hi_im[m];
        lo_re[m] += hi_re[m];
        lo_im[m] += hi_im[m];
        hi_re[m] = dr * wr[m] - di * wi[m];
        hi_im[m] = dr * wi[m] + di * wr[m];
      }
    }
  }

  void InverseStage(double* re, double* im, size_t h) const {
    const double* wr = &cos_[h - 1];
    const double* ws = &sin_[h - 1];
    for (size_t start = 0; start < n_; start += 2 * h) {
      double* lo_re = re + start;
      double* lo_im = im + start;
      double* hi_re = re + start + h;
      double* hi_im = im + start + h;
      for (size_t m = 0; m < h; ++m) {
        // Conjugate twiddle: exp(+i pi m / h).
        const double wi = -ws[m];
        const double tr = hi_re[m] * wr[m] - hi_im[m] * wi;
        const double ti = hi_re[m] * wi + hi_im[m] * wr[m];
        hi_re[m] = lo_re[m] - tr;
        hi_im[m] = lo_im[m] - ti;
        lo_re[m] += tr;
        lo_im[m] += ti;
      }
    }
  }

  size_t n_;
  std::vector<double> cos_;
  std::vector<double> sin_;
};

// Centres series[0..n-1] and scales it to unit sum of squares. Returns false, leaving zeros,
// when the series is constant.
bool Normalise(int n, double* series) {
  double mean = 0.0;
  for (int t = 0; t < n; ++t) mean += series[t];
  mean /= n;
  double sum_sq = 0.0;
  for (int t = 0; t < n; ++t) {
    series[t] -= mean;
    sum_sq += series[t] * series[t];
  }
  if (!(sum_sq > 0.0) || !std::isfinite(sum_sq)) {
    std::fill(series, series + n, 0.0);
    return false;
  }
  const double scale = 1.0 / std::sqrt(sum_sq);
  for (int t = 0; t < n; ++t) series[t] *= scale;
  return true;
}

}  // namespace

// Method. With each series y_w centred and scaled to sum_t y_w(t)^2 = 1, its normalised
// autocorrelation is rho_w(t) = sum_s y_w(s) y_w(s + t), so the ensemble average is
//   rho(t) = (1/W) sum_w sum_s y_w(s) y_w(s + t).
// Two series go into one complex sequence z = a + i b, for which
//   Re sum_s conj(z(s)) z(s + t) = sum_s a(s) a(s + t) + b(s) b(s + t),
// and, zero-padded to >= 2n so that circular lags do not wrap, that sum is the inverse FFT of
// |Z_k|^2. The inverse transform being linear, the power spectra of all pairs are summed
// first and transformed back once: W / 2 + 1 transforms per ensemble instead of 2 W.
std::vector<double> EnsembleAutocorrelationFunction(const double* data, int num_steps,
                                                    int num_series, std::ptrdiff_t step_stride,
                                                    std::ptrdiff_t series_stride) {
  if (num_steps < 1 || num_series < 1) return {};
  const int n = num_steps;
  size_t fft_size = 1;
  while (fft_size < 2 * static_cast<size_t>(n)) fft_size <<= 1;
  const Fft fft(fft_size);

  // All series, one after another. Gathered step by step, because in a sampler chain the
  // walkers of one step are neighbours in memory while one walker's steps are far apart.
  std::vector<double> series(static_cast<size_t>(n) * num_series);
  for (int t = 0; t < n; ++t) {
    const double* row = data + t * step_stride;
    for (int s = 0; s < num_series; ++s) {
      series[static_cast<size_t>(s) * n + t] = row[s * series_stride];
    }
  }
  int constant_series = 0;
  for (int s = 0; s < num_series; ++s) {
    if (!Normalise(n, &series[static_cast<size_t>(s) * n])) ++constant_series;
  }

  std::vector<double> re(fft_size), im(fft_size);
  std::vector<double> power(fft_size, 0.0);
  for (int s = 0; s < num_series; s += 2) {
    const double* a = &series[static_cast<size_t>(s) * n];
    std::copy(a, a + n, re.begin());
    std::fill(re.begin() + n, re.end(), 0.0);
    if (s + 1 < num_series) {
      const double* b = a + n;
      std::copy(b, b + n, im.begin());
      std::fill(im.begin() + n, im.end(), 0.0);
    } else {
      std::fill(im.begin(), im.end(), 0.0);
    }
    fft.Forward(re.data(), im.data());
    for (size_t k = 0; k < fft_size; ++k) power[k] += re[k] * re[k] + im[k] * im[k];
  }
  std::fill(im.begin(), im.end(), 0.0);
  fft.Inverse(power.data(), im.data());

  // power[t] = fft_size * sum_w rho_w(t) over the non-constant series; a constant series
  // contributes rho = 1 at every lag (see the header).
  std::vector<double> rho(n);
  const double scale = 1.0 / static_cast<double>(fft_size);
  for (int t = 0; t < n; ++t) {
    rho[t] = (power[t] * scale + constant_series) / num_series;
  }
  return rho;
}

std::vector<double> AutocorrelationFunction(const std::vector<double>& x) {
  return EnsembleAutocorrelationFunction(x.data(), static_cast<int>(x.size()), 1, 1, 0);
}

std::optional<AutocorrelationTime> IntegratedTimeFromAcf(const std::vector<double>& rho, double c) {
  if (rho.size() < 2 || !(c > 0.0)) return std::nullopt;
  AutocorrelationTime result;
  double tau = 1.0;
  for (size_t m = 1; m < rho.size(); ++m) {
    tau += 2.0 * rho[m];
    result.tau = tau;
    result.window = static_cast<int>(m);
    if (static_cast<double>(m) >= c * tau) {
      result.window_found = true;
      break;
    }
  }
  return result;
}

std::optional<AutocorrelationTime> EnsembleIntegratedAutocorrelationTime(
    const double* data, int num_steps, int num_series, std::ptrdiff_t step_stride,
    std::ptrdiff_t series_stride, double c) {
  if (num_steps < 2 || num_series < 1 || !(c > 0.0)) return std::nullopt;
  return IntegratedTimeFromAcf(
      EnsembleAutocorrelationFunction(data, num_steps, num_series, step_stride, series_stride), c);
}

std::optional<AutocorrelationTime> IntegratedAutocorrelationTime(const std::vector<double>& x,
                                                                 double c) {
  return EnsembleIntegratedAutocorrelationTime(x.data(), static_cast<int>(x.size()), 1, 1, 0, c);
}

double EffectiveSampleSize(int num_walkers, int num_steps, double tau) {
  if (!(tau > 0.0) || !std::isfinite(tau)) return 0.0;
  return static_cast<double>(num_walkers) * static_cast<double>(num_steps) / tau;
}

}  // namespace ccdpsf::fit
