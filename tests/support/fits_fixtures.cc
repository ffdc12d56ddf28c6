#include "support/fits_fixtures.h"

#include <fitsio.h>
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <variant>

namespace ccdpsf::test_support {

ScopedTempDir::ScopedTempDir() {
  std::string base = ::testing::TempDir();
  if (base.empty()) base = "/tmp/";
  if (base.back() != '/') base += '/';
  std::string pattern = base + "ccdpsf_fits_XXXXXX";
  std::vector<char> buffer(pattern.begin(), pattern.end());
  buffer.push_back('\0');
  if (::mkdtemp(buffer.data()) != nullptr) path_ = buffer.data();
  EXPECT_FALSE(path_.empty()) << "mkdtemp failed for " << pattern;
}

ScopedTempDir::~ScopedTempDir() {
  if (path_.empty()) return;
  std::error_code ignored;
  std::filesystem::remove_all(path_, ignored);
}

std::string ScopedTempDir::File(const std::string& name) const { return path_ + "/" + name; }

std::vector<std::string> ScopedTempDir::List() const {
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(path_, ec)) {
    names.push_back(entry.path().filename().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

namespace {

std::string StatusText(int status) {
  char text[FLEN_STATUS] = {0};
  fits_get_errstatus(status, text);
  fits_clear_errmsg();
  return "cfitsio status " + std::to_string(status) + ": " + text;
}

void WriteKeys(fitsfile* file, const FitsHeader& keys, int* status) {
  for (const FitsKey& key : keys) {
    if (const double* v = std::get_if<double>(&key.value)) {
      fits_update_key_dbl(file, key.name.c_str(), *v, -15, key.comment.c_str(), status);
    } else if (const long long* v = std::get_if<long long>(&key.value)) {
      fits_update_key_lng(file, key.name.c_str(), *v, key.comment.c_str(), status);
    } else if (const bool* v = std::get_if<bool>(&key.value)) {
      fits_update_key_log(file, key.name.c_str(), *v ? 1 : 0, key.comment.c_str(), status);
    } else {
      fits_update_key_str(file, key.name.c_str(), std::get<std::string>(key.value).c_str(),
                          key.comment.c_str(), status);
    }
  }
}

}  // namespace

bool WriteRawFits(const std::string& path, const RawImageSpec& spec, std::string* error) {
  ::unlink(path.c_str());
  fitsfile* file = nullptr;
  int status = 0;
  fits_create_diskfile(&file, path.c_str(), &status);
  if (status == 0 && spec.in_extension) {
    fits_create_img(file, BYTE_IMG, 0, nullptr, &status);
  }
  std::vector<long> naxes = spec.naxes;
  fits_create_img(file, spec.bitpix, static_cast<int>(naxes.size()),
                  naxes.empty() ? nullptr : naxes.data(), &status);
  if (spec.in_extension) {
    fits_update_key_str(file, "EXTNAME", "SCI", "", &status);
  }
  if (spec.bscale) fits_update_key_dbl(file, "BSCALE", *spec.bscale, -15, "", &status);
  if (spec.bzero) fits_update_key_dbl(file, "BZERO", *spec.bzero, -15, "", &status);
  if (spec.blank) fits_update_key_lng(file, "BLANK", *spec.blank, "", &status);
  WriteKeys(file, spec.keys, &status);
  // Store the raw values as given: no scaling, no null substitution. (fits_set_bscale does
  // not check the status it is given, so it must not run after a failure.)
  if (status == 0 && !spec.raw.empty()) {
    fits_set_bscale(file, 1.0, 0.0, &status);
    std::vector<double> raw = spec.raw;
    fits_write_img(file, TDOUBLE, 1, static_cast<LONGLONG>(raw.size()), raw.data(), &status);
  }
  int close_status = 0;
  if (file != nullptr) fits_close_file(file, &close_status);
  if (status == 0) status = close_status;
  if (status != 0) {
    *error = StatusText(status);
    return false;
  }
  return true;
}

bool WriteTableOnlyFits(const std::string& path, std::string* error) {
  ::unlink(path.c_str());
  fitsfile* file = nullptr;
  int status = 0;
  fits_create_diskfile(&file, path.c_str(), &status);
  fits_create_img(file, BYTE_IMG, 0, nullptr, &status);
  char name[] = "FLUX";
  char form[] = "1D";
  char unit[] = "e-";
  char* ttype[] = {name};
  char* tform[] = {form};
  char* tunit[] = {unit};
  fits_create_tbl(file, BINARY_TBL, 3, 1, ttype, tform, tunit, "SPOTS", &status);
  double values[3] = {1.0, 2.0, 3.0};
  fits_write_col(file, TDOUBLE, 1, 1, 1, 3, values, &status);
  int close_status = 0;
  if (file != nullptr) fits_close_file(file, &close_status);
  if (status == 0) status = close_status;
  if (status != 0) {
    *error = StatusText(status);
    return false;
  }
  return true;
}

bool WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  return static_cast<bool>(out);
}

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream contents;
  contents << in.rdbuf();
  return contents.str();
}

namespace {

// Fraction of a unit 1-D Gaussian (centre mu, width sigma) falling in [a, b].
double GaussianFraction(double a, double b, double mu, double sigma) {
  const double s = sigma * std::sqrt(2.0);
  return 0.5 * (std::erf((b - mu) / s) - std::erf((a - mu) / s));
}

}  // namespace

double ExpectedElectrons(const SyntheticFrame& spec, int x, int y) {
  return spec.flux_e * GaussianFraction(x - 0.5, x + 0.5, spec.spot_x_px, spec.sigma_px) *
         GaussianFraction(y - 0.5, y + 0.5, spec.spot_y_px, spec.sigma_px);
}

Image MakeSpotFrame(const SyntheticFrame& spec) {
  std::mt19937_64 rng(spec.seed);
  std::normal_distribution<double> read_noise(0.0, spec.read_noise_e);
  Image frame(spec.nx, spec.ny);
  for (int y = 0; y < spec.ny; ++y) {
    for (int x = 0; x < spec.nx; ++x) {
      double electrons = ExpectedElectrons(spec, x, y);
      if (spec.noise) {
        if (electrons > 0.0) {
          std::poisson_distribution<long long> shot(electrons);
          electrons = static_cast<double>(shot(rng));
        }
        electrons += read_noise(rng);
      }
      double adu = spec.bias_adu + electrons / spec.gain_e_per_adu;
      if (spec.round) adu = std::round(adu);
      frame(x, y) = adu;
    }
  }
  return frame;
}

}  // namespace ccdpsf::test_support
