// Pixel conventions, stated once for the whole project.
//
// Coordinates are 0-based pixel indices with pixel centres at integers, as in numpy and
// astropy: pixel (i, j) covers [i - 0.5, i + 0.5] x [j - 0.5, j + 0.5]. x is the column index
// (FITS NAXIS1, the serial direction), y the row index (NAXIS2, the parallel direction).
// Images are stored row-major: element (x, y) sits at data[y * nx + x], which is also the
// order CFITSIO reads and writes.
#ifndef CCDPSF_IMAGE_H_
#define CCDPSF_IMAGE_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace ccdpsf {

// A dense 2-D array of doubles in the convention above. The unit is the caller's (ADU,
// electrons, ...) and is named where the image is held.
struct Image {
  Image() = default;
  Image(int nx_in, int ny_in, double fill = 0.0)
      : nx(nx_in), ny(ny_in), data(static_cast<size_t>(nx_in) * ny_in, fill) {}

  double& operator()(int x, int y) { return data[static_cast<size_t>(y) * nx + x]; }
  double operator()(int x, int y) const { return data[static_cast<size_t>(y) * nx + x]; }
  size_t size() const { return data.size(); }
  bool empty() const { return data.empty(); }

  int nx = 0;
  int ny = 0;
  std::vector<double> data;
};

// What is known about the exposure a stamp was cut from. NaN means "not known" for every
// floating-point field.
struct ExposureInfo {
  std::string source;  // file the data came from
  double wavelength_nm = std::numeric_limits<double>::quiet_NaN();
  double exptime_s = std::numeric_limits<double>::quiet_NaN();
  // Pixel pitch [um]: 12 (VIS CCD273) for stamps built in code (simulations, tests);
  // calibration sets it from the file's metadata, NaN when nothing gives it.
  double pixel_um = 12.0;
  double focus_position_um = std::numeric_limits<double>::quiet_NaN();
};

// How a stamp pixel enters the likelihood (Stamp::censor). A censored pixel's true value is
// known only to lie beyond its recorded level: at or above it (saturation, the ADC's top, a
// clipped amplifier) or at or below it (a black level clipped at the ADC's zero).
enum class Censor : uint8_t { kNone = 0, kAtOrAbove = 1, kAtOrBelow = 2 };

// A calibrated cut-out around one spot: what every fit consumes.
//
// electrons holds (data_adu - bias_adu) * gain_e_per_adu: the bias-subtracted signal in
// electrons. valid is 1 for pixels that enter the likelihood and 0 for masked ones
// (non-finite, flagged by a mask, contaminated); a masked pixel's value is meaningless.
// censor (empty, or one entry per pixel) marks valid pixels that are censored; their
// electrons hold the censoring level. adc_step_e is one ADU in electrons for integer data
// (the recorded value stands for [value - 0.5, value + 0.5) ADU), 0 for floating-point data.
// Stamp pixel (i, j) is frame pixel (origin_x + i, origin_y + j).
struct Stamp {
  Image electrons;
  std::vector<uint8_t> valid;
  std::vector<Censor> censor;
  int origin_x = 0;
  int origin_y = 0;
  double gain_e_per_adu = 1.0;
  double read_noise_e = 0.0;
  double bias_adu = 0.0;
  double saturation_adu = std::numeric_limits<double>::infinity();
  double adc_step_e = 0.0;
  ExposureInfo info;

  int nx() const { return electrons.nx; }
  int ny() const { return electrons.ny; }
  int NumValid() const {
    int n = 0;
    for (uint8_t v : valid) n += v ? 1 : 0;
    return n;
  }
  Censor CensorAt(size_t q) const { return censor.empty() ? Censor::kNone : censor[q]; }
  // A valid pixel whose value is a measurement, not a censoring bound: what statistics of
  // residuals may use.
  bool Measured(size_t q) const { return valid[q] && CensorAt(q) == Censor::kNone; }
  int NumCensored() const {
    int n = 0;
    for (size_t q = 0; q < censor.size(); ++q) n += valid[q] && censor[q] != Censor::kNone;
    return n;
  }
};

// The stage positions (FOCUSPOS) the stamps were taken at, sorted, each once [um]; stamps
// without one are left out. Positions are distinct when unequal (no tolerance): a focus
// series (three or more) for fit, a refusal for diagnose (two or more).
inline std::vector<double> DistinctFocusPositions(const std::vector<Stamp>& stamps) {
  std::vector<double> z;
  for (const Stamp& s : stamps) {
    if (std::isfinite(s.info.focus_position_um)) z.push_back(s.info.focus_position_um);
  }
  std::sort(z.begin(), z.end());
  z.erase(std::unique(z.begin(), z.end()), z.end());
  return z;
}

}  // namespace ccdpsf

#endif  // CCDPSF_IMAGE_H_
