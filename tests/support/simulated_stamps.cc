#include "support/simulated_stamps.h"

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
    s.gain_e_per_adu = c.gain_e_per_adu;
    s.read_noise_e = c.read_noise_e;
    s.bias_adu = c.bias_adu;
    s.info.wavelength_nm = c.exposures[k].wavelength_nm;
    s.info.source = "simulated_" + std::to_string(k);
    stamps.push_back(s);
  }
  return stamps;
}

}  // namespace ccdpsf::testing_support
