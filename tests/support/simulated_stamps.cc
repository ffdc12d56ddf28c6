#include "support/simulated_stamps.h"

#include <algorithm>
#include <cmath>

#include "ccdpsf/random.h"

namespace ccdpsf::testing_support {

SimulationConfig PaperConfig(model::Sampling sampling, int count, uint64_t seed) {
  SimulationConfig c;
  c.seed = seed;
  c.nx = c.ny = 21;
  c.model.sampling = sampling;
  c.airy_radius_px = 0.47;
  c.defocus_px = 0.41;
  c.ccd_sigma_x_px = 0.291;
  c.ccd_sigma_y_px = 0.335;
  std::mt19937_64 engine(DeriveSeed(seed, 999));
  for (int k = 0; k < count; ++k) {
    SimulatedExposure e;
    // 4.0e5 e- total puts ~1.5e5 e- in the peak pixel for these widths.
    e.flux_e = sampling == model::Sampling::kIntegrated ? 4.0e5 : 1.5e5;
    e.x_px = 10.0 + 0.2 * (Uniform01(engine) - 0.5);
    e.y_px = 10.0 + 0.2 * (Uniform01(engine) - 0.5);
    e.wavelength_nm = 800;
    e.exptime_s = 2.5;
    c.exposures.push_back(e);
  }
  return c;
}

SimulationConfig FocusSeriesConfig(const std::vector<double>& z_um, double best_focus_um,
                                   double rate_px_per_um, double flux_e, uint64_t seed) {
  SimulationConfig c = PaperConfig(model::Sampling::kIntegrated, static_cast<int>(z_um.size()),
                                    seed);
  for (size_t k = 0; k < z_um.size(); ++k) {
    c.exposures[k].flux_e = flux_e;
    c.exposures[k].focus_position_um = z_um[k];
    c.exposures[k].defocus_px = rate_px_per_um * std::fabs(z_um[k] - best_focus_um);
  }
  return c;
}

std::vector<Stamp> SimulateStamps(const SimulationConfig& c, uint64_t noise_seed) {
  std::vector<Stamp> stamps;
  for (size_t k = 0; k < c.exposures.size(); ++k) {
    const Image expected = ExpectedElectrons(c, c.exposures[k]);
    std::mt19937_64 engine(DeriveSeed(noise_seed, k));
    const Image adu = ObserveAdu(c, expected, engine);
    Stamp s;
    s.electrons = Image(adu.nx, adu.ny);
    for (size_t q = 0; q < adu.size(); ++q) {
      s.electrons.data[q] = (adu.data[q] - c.bias_adu) * c.gain_e_per_adu;
    }
    s.valid.assign(adu.size(), 1);
    for (size_t q = 0; q < adu.size(); ++q) {
      if (adu.data[q] >= std::min(65535.0, c.saturation_adu)) s.valid[q] = 0;
    }
    s.gain_e_per_adu = c.gain_e_per_adu;
    s.read_noise_e = c.read_noise_e;
    s.bias_adu = c.bias_adu;
    s.info.wavelength_nm = c.exposures[k].wavelength_nm;
    s.info.focus_position_um = c.exposures[k].focus_position_um.value_or(NAN);
    s.info.source = "simulated_" + std::to_string(k);
    stamps.push_back(s);
  }
  return stamps;
}

}  // namespace ccdpsf::testing_support
