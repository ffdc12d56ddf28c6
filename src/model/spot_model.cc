#include "ccdpsf/model/spot_model.h"

#include <cmath>
#include <sstream>

namespace ccdpsf::model {

bool ParseSampling(const std::string& text, Sampling* sampling) {
  if (text == "integrated") {
    *sampling = Sampling::kIntegrated;
  } else if (text == "pixel_centre") {
    *sampling = Sampling::kPixelCentre;
  } else {
    return false;
  }
  return true;
}

bool ParseDefocusKind(const std::string& text, DefocusKind* kind) {
  if (text == "gaussian") {
    *kind = DefocusKind::kGaussian;
  } else if (text == "pillbox") {
    *kind = DefocusKind::kPillbox;
  } else {
    return false;
  }
  return true;
}

std::string ToString(Sampling sampling) {
  return sampling == Sampling::kIntegrated ? "integrated" : "pixel_centre";
}

std::string ToString(DefocusKind kind) {
  return kind == DefocusKind::kGaussian ? "gaussian" : "pillbox";
}

bool ValidSpotParams(const ModelOptions& options, const SpotParams& p, std::string* error) {
  static const char* kNames[kNumSpotParams] = {"flux", "x", "y", "airy radius", "defocus",
                                               "ccd sigma_x", "ccd sigma_y"};
  for (int i = 0; i < kNumSpotParams; ++i) {
    if (!std::isfinite(p[i])) {
      *error = std::string("model parameter ") + kNames[i] + " is not finite";
      return false;
    }
  }
  // Plain comparisons first; the reason is written only when one fails (an ostringstream
  // built on every render cost ~3 % of a values-only render).
  const bool window_ok = options.pixel_response_width > 0.0 && options.pixel_response_width <= 1.0;
  const bool integrated = options.sampling == Sampling::kIntegrated;
  // The quadrature needs some Gaussian smoothing on each axis: its node spacing scales with
  // the smallest total width (see integrated_renderer.cc).
  const bool gaussian = options.defocus == DefocusKind::kGaussian;
  const double gx = integrated && gaussian ? std::hypot(p[kDefocus], p[kCcdSigmaX]) : p[kCcdSigmaX];
  const double gy = integrated && gaussian ? std::hypot(p[kDefocus], p[kCcdSigmaY]) : p[kCcdSigmaY];
  const bool widths_ok = gx >= kMinGaussianWidthPx && gy >= kMinGaussianWidthPx;
  const bool radius_ok = p[kAiryRadius] >= kMinAiryRadiusPx;
  // (A defocus of 0 is "no defocus step" for pixel_centre sampling: pixel_centre_renderer.cc.)
  const bool sampling_ok =
      integrated ? widths_ok && radius_ok : p[kCcdSigmaX] > 0 && p[kCcdSigmaY] > 0;
  if (window_ok && p[kFlux] >= 0 && p[kAiryRadius] > 0 && p[kDefocus] >= 0 && p[kCcdSigmaX] >= 0 &&
      p[kCcdSigmaY] >= 0 && sampling_ok) {
    return true;
  }
  std::ostringstream why;
  if (!window_ok) {
    why << "the pixel response width must lie in (0, 1] px (got "
        << options.pixel_response_width << ")";
  } else if (p[kFlux] < 0) {
    why << "flux must be >= 0 (got " << p[kFlux] << ")";
  } else if (p[kAiryRadius] <= 0) {
    why << "airy radius must be > 0 px (got " << p[kAiryRadius] << ")";
  } else if (p[kDefocus] < 0) {
    why << "defocus must be >= 0 px (got " << p[kDefocus] << ")";
  } else if (p[kCcdSigmaX] < 0 || p[kCcdSigmaY] < 0) {
    why << "ccd sigmas must be >= 0 px";
  } else if (integrated) {
    if (!widths_ok) {
      why << "integrated sampling needs a total Gaussian width >= " << kMinGaussianWidthPx
          << " px on each axis (got " << gx << ", " << gy << ")";
    }
    if (!radius_ok) why << "airy radius must be >= " << kMinAiryRadiusPx << " px";
  } else {
    why << "pixel_centre sampling needs ccd sigmas > 0 px";
  }
  *error = why.str();
  return false;
}

}  // namespace ccdpsf::model
