// The image effects of effects.h (halo, nonlinearity, ipc, serial_cti, parallel_cti,
// background), each written once, on images that carry forward-mode derivatives. The
// simulator calls them with no derivative channel; a fit (fit_model.cc) with one channel per
// parameter it depends on, so that the values are the same arithmetic in both.
#include <algorithm>
#include <cmath>

#include "ccdpsf/model/effects.h"
#include "glog/logging.h"

namespace ccdpsf::model {
namespace {

// The Gaussian density of sigma s at t.
double Density(double t, double s) {
  return std::exp(-0.5 * t * t / (s * s)) / (s * std::sqrt(2.0 * M_PI));
}

// One CTI pass along a line of `n` pixels spaced `pixel_stride` pixels apart, each carrying
// `channels` values (value, then derivatives; effects.h):
//   out[i] = (1 - f) in[i] + f (1 - r) T[i],  T[0] = 0,  T[i + 1] = in[i] + r T[i],
// applied to every channel (the operator is linear), plus the derivatives in f and in the
// trail length L (r = exp(-1 / L), dr/dL = r / L^2; dT/dr = D with D[i + 1] = T[i] + r D[i])
// into channels `f_channel` and `length_channel` (-1: not wanted). `trail` is scratch.
void CtiLine(const CtiParams& cti, int n, int pixel_stride, int channels, int f_channel,
             int length_channel, double* v, std::vector<double>* trail) {
  const double f = cti.trail_fraction, length = cti.trail_length_px;
  const double r = std::exp(-1.0 / length);
  const double dr_dlength = r / (length * length);
  trail->assign(channels, 0.0);
  double* t = trail->data();
  double d_trail_dr = 0.0;
  const size_t step = static_cast<size_t>(pixel_stride) * channels;
  for (int i = 0; i < n; ++i) {
    double* p = v + i * step;
    const double in = p[0], t0 = t[0];
    p[0] = (1.0 - f) * in + f * (1.0 - r) * t0;
    t[0] = in + r * t0;
    for (int c = 1; c < channels; ++c) {
      const double in_c = p[c];
      p[c] = (1.0 - f) * in_c + f * (1.0 - r) * t[c];
      t[c] = in_c + r * t[c];
    }
    if (f_channel >= 0) p[f_channel] += (1.0 - r) * t0 - in;
    if (length_channel >= 0) p[length_channel] += f * ((1.0 - r) * d_trail_dr - t0) * dr_dlength;
    d_trail_dr = t0 + r * d_trail_dr;
  }
}

}  // namespace

EffectChannels::EffectChannels() {
  for (auto& kind : channel_) kind.fill(-1);
}

int EffectChannels::Get(EffectKind kind, int parameter) const {
  return channel_[static_cast<int>(kind)][parameter];
}

void EffectChannels::Set(EffectKind kind, int parameter, int channel) {
  CHECK_LT(parameter, kMaxEffectParameters);
  channel_[static_cast<int>(kind)][parameter] = channel;
}

double GaussianIntervalIntegral(double a, double b, double sigma) {
  CHECK_GT(sigma, 0.0);
  const double k = 1.0 / (sigma * M_SQRT2);
  if (a >= 0.0) return 0.5 * (std::erfc(a * k) - std::erfc(b * k));    // right tail
  if (b <= 0.0) return 0.5 * (std::erfc(-b * k) - std::erfc(-a * k));  // left tail
  return 0.5 * (std::erf(b * k) - std::erf(a * k));
}

void AddHalo(const HaloParams& halo, const PixelGrid& grid, const SpotReference& spot,
             const SpotReferenceDerivatives* spot_d, const EffectChannels& channels,
             DualImage* image) {
  const int s = image->stride(), nd = image->num_derivatives;
  const double sigma = halo.sigma_px;
  // Per column i and row j: the halo's integral over the pixel, and its derivatives in the
  // spot centre (moving the centre by +d moves the interval by -d) and in sigma.
  std::vector<double> hx(grid.nx), hy(grid.ny), hx_c(grid.nx), hy_c(grid.ny), hx_s(grid.nx),
      hy_s(grid.ny);
  auto fill = [&](double first_edge, int n, double* h, double* h_c, double* h_s) {
    for (int i = 0; i < n; ++i) {
      const double a = first_edge + i, b = a + 1.0;
      h[i] = GaussianIntervalIntegral(a, b, sigma);
      const double da = Density(a, sigma), db = Density(b, sigma);
      h_c[i] = da - db;
      h_s[i] = (a * da - b * db) / sigma;
    }
  };
  fill(grid.x0 - 0.5 - spot.x_px, grid.nx, hx.data(), hx_c.data(), hx_s.data());
  fill(grid.y0 - 0.5 - spot.y_px, grid.ny, hy.data(), hy_c.data(), hy_s.data());
  const double f = halo.fraction, keep = 1.0 - f;
  const double moved = f * spot.flux_e;
  const int f_channel = channels.Get(EffectKind::kHalo, 0);
  const int sigma_channel = channels.Get(EffectKind::kHalo, 1);
  for (int j = 0; j < grid.ny; ++j) {
    for (int i = 0; i < grid.nx; ++i) {
      double* p = image->data.data() + (static_cast<size_t>(j) * grid.nx + i) * s;
      const double in = p[0];
      const double h = hx[i] * hy[j];
      p[0] = keep * in + moved * hx[i] * hy[j];
      for (int c = 1; c <= nd; ++c) {
        double d = keep * p[c];
        if (spot_d != nullptr) {
          d += f *
               (spot_d->flux_e[c - 1] * h + spot.flux_e * (hx_c[i] * hy[j] * spot_d->x_px[c - 1] +
                                                           hx[i] * hy_c[j] * spot_d->y_px[c - 1]));
        }
        p[c] = d;
      }
      if (f_channel >= 0) p[f_channel] += spot.flux_e * h - in;
      if (sigma_channel >= 0) p[sigma_channel] += moved * (hx_s[i] * hy[j] + hx[i] * hy_s[j]);
    }
  }
}

void ApplyNonlinearity(const NonlinearityParams& nl, const EffectChannels& channels,
                       DualImage* image) {
  const double beta = nl.beta_per_e;
  const int s = image->stride(), beta_channel = channels.Get(EffectKind::kNonlinearity, 0);
  if (beta == 0.0 && beta_channel < 0) return;
  const double turning = beta > 0.0 ? 0.5 / beta : INFINITY;
  const size_t size = static_cast<size_t>(image->nx) * image->ny;
  for (size_t q = 0; q < size; ++q) {
    double* p = image->data.data() + q * s;
    const double in = p[0];
    if (in >= turning) {  // the full well: the response held at its maximum
      p[0] = 0.25 / beta;
      for (int c = 1; c < s; ++c) p[c] = 0.0;
      if (beta_channel >= 0) p[beta_channel] = -0.25 / (beta * beta);
      continue;
    }
    p[0] = in * (1.0 - beta * in);
    const double slope = 1.0 - 2.0 * beta * in;
    for (int c = 1; c < s; ++c) p[c] *= slope;
    if (beta_channel >= 0) p[beta_channel] -= in * in;
  }
}

void ApplyIpc(const IpcParams& ipc, const EffectChannels& channels, DualImage* image) {
  const double a = ipc.alpha;
  const int nx = image->nx, ny = image->ny, s = image->stride();
  const int alpha_channel = channels.Get(EffectKind::kIpc, 0);
  const std::vector<double> in = image->data;
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      const size_t q = static_cast<size_t>(j) * nx + i;
      double own = 0.0;  // d out / d alpha
      for (int c = 0; c < s; ++c) {
        double neighbours = 0.0;
        if (i > 0) neighbours += in[(q - 1) * s + c];
        if (i + 1 < nx) neighbours += in[(q + 1) * s + c];
        if (j > 0) neighbours += in[(q - nx) * s + c];
        if (j + 1 < ny) neighbours += in[(q + nx) * s + c];
        image->data[q * s + c] = (1.0 - 4.0 * a) * in[q * s + c] + a * neighbours;
        if (c == 0) own = neighbours - 4.0 * in[q * s];
      }
      if (alpha_channel >= 0) image->data[q * s + alpha_channel] += own;
    }
  }
}

void ApplySerialCti(const CtiParams& cti, const EffectChannels& channels, DualImage* image) {
  std::vector<double> trail;
  const int s = image->stride();
  for (int j = 0; j < image->ny; ++j) {
    CtiLine(cti, image->nx, 1, s, channels.Get(EffectKind::kSerialCti, 0),
            channels.Get(EffectKind::kSerialCti, 1),
            image->data.data() + static_cast<size_t>(j) * image->nx * s, &trail);
  }
}

void ApplyParallelCti(const CtiParams& cti, const EffectChannels& channels, DualImage* image) {
  std::vector<double> trail;
  const int s = image->stride();
  for (int i = 0; i < image->nx; ++i) {
    CtiLine(cti, image->ny, image->nx, s, channels.Get(EffectKind::kParallelCti, 0),
            channels.Get(EffectKind::kParallelCti, 1), image->data.data() + i * s, &trail);
  }
}

void AddBackground(const BackgroundParams& background, const EffectChannels& channels,
                   DualImage* image) {
  const int s = image->stride(), channel = channels.Get(EffectKind::kBackground, 0);
  const size_t size = static_cast<size_t>(image->nx) * image->ny;
  for (size_t q = 0; q < size; ++q) {
    image->data[q * s] += background.pedestal_e;
    if (channel >= 0) image->data[q * s + channel] += 1.0;
  }
}

void ApplyChargeEffects(const ExposureEffects& e, const PixelGrid& grid, const SpotReference& spot,
                        const SpotReferenceDerivatives* spot_d, const EffectChannels& channels,
                        DualImage* image) {
  CHECK_EQ(image->nx, grid.nx);
  CHECK_EQ(image->ny, grid.ny);
  if (e.halo) AddHalo(*e.halo, grid, spot, spot_d, channels, image);
  if (e.nonlinearity) ApplyNonlinearity(*e.nonlinearity, channels, image);
  if (e.ipc) ApplyIpc(*e.ipc, channels, image);
  if (e.serial_cti) ApplySerialCti(*e.serial_cti, channels, image);
  if (e.parallel_cti) ApplyParallelCti(*e.parallel_cti, channels, image);
}

void ApplyImageEffects(const ExposureEffects& e, const PixelGrid& grid, const SpotReference& spot,
                       const SpotReferenceDerivatives* spot_d, const EffectChannels& channels,
                       DualImage* image) {
  ApplyChargeEffects(e, grid, spot, spot_d, channels, image);
  if (e.background) AddBackground(*e.background, channels, image);
}

// ---------------------------------------------------------------------------------------
// Value-only forms: a DualImage without derivative channels over the caller's image.

namespace {

template <typename Apply>
void OnValues(int nx, int ny, double* image, Apply apply) {
  DualImage dual;
  dual.nx = nx;
  dual.ny = ny;
  dual.data.assign(image, image + static_cast<size_t>(nx) * ny);
  apply(&dual);
  std::copy(dual.data.begin(), dual.data.end(), image);
}

}  // namespace

void AddHalo(const HaloParams& halo, const PixelGrid& grid, const SpotReference& spot,
             double* image) {
  OnValues(grid.nx, grid.ny, image,
           [&](DualImage* d) { AddHalo(halo, grid, spot, nullptr, EffectChannels(), d); });
}
void ApplyNonlinearity(const NonlinearityParams& nl, int size, double* image) {
  OnValues(size, 1, image, [&](DualImage* d) { ApplyNonlinearity(nl, EffectChannels(), d); });
}
void ApplyIpc(const IpcParams& ipc, int nx, int ny, double* image) {
  OnValues(nx, ny, image, [&](DualImage* d) { ApplyIpc(ipc, EffectChannels(), d); });
}
void ApplySerialCti(const CtiParams& cti, int nx, int ny, double* image) {
  OnValues(nx, ny, image, [&](DualImage* d) { ApplySerialCti(cti, EffectChannels(), d); });
}
void ApplyParallelCti(const CtiParams& cti, int nx, int ny, double* image) {
  OnValues(nx, ny, image, [&](DualImage* d) { ApplyParallelCti(cti, EffectChannels(), d); });
}
void AddBackground(const BackgroundParams& background, int size, double* image) {
  OnValues(size, 1, image, [&](DualImage* d) { AddBackground(background, EffectChannels(), d); });
}
void ApplyChargeEffects(const ExposureEffects& e, const PixelGrid& grid, const SpotReference& spot,
                        double* image) {
  OnValues(grid.nx, grid.ny, image,
           [&](DualImage* d) { ApplyChargeEffects(e, grid, spot, nullptr, EffectChannels(), d); });
}
void ApplyImageEffects(const ExposureEffects& e, const PixelGrid& grid, const SpotReference& spot,
                       double* image) {
  OnValues(grid.nx, grid.ny, image,
           [&](DualImage* d) { ApplyImageEffects(e, grid, spot, nullptr, EffectChannels(), d); });
}

}  // namespace ccdpsf::model
