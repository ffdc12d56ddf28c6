// Calibrated stamps straight from the simulator, without a FITS round trip: for fit tests
// that need many data sets quickly. The FITS path is covered by the CLI tests.
#ifndef CCDPSF_TESTS_SUPPORT_SIMULATED_STAMPS_H_
#define CCDPSF_TESTS_SUPPORT_SIMULATED_STAMPS_H_

#include <cstdint>
#include <vector>

#include "ccdpsf/image.h"
#include "ccdpsf/simulate.h"

namespace ccdpsf::testing_support {

// The paper's simulation (section 3.3): r 0.47, Gaussian defocus 0.41, CCD (0.291, 0.335),
// gain 3.1, read noise 4.5 e-, bias 1000 ADU, 21 x 21 frames; `count` exposures with
// centres jittered by up to +-0.1 px around (10, 10) (deterministic in `seed`), flux giving a
// ~1.5e5 e- peak pixel (integrated) or peak_e = 1.5e5 (pixel_centre).
SimulationConfig PaperConfig(model::Sampling sampling, int count, uint64_t seed);

// A through-focus series (integrated sampling, Gaussian defocus) with the paper's Airy
// radius and CCD kernel: one exposure per stage position z_um[k] [um], each with defocus
// sigma rate_px_per_um |z - best_focus_um| [px] and total flux flux_e, centres jittered by up
// to +-0.1 px around (10, 10) (deterministic in `seed`).
SimulationConfig FocusSeriesConfig(const std::vector<double>& z_um, double best_focus_um,
                                   double rate_px_per_um, double flux_e, uint64_t seed);

// One noisy realisation of every exposure, calibrated as the reader would (known bias and
// gain, saturated pixels masked, FOCUSPOS carried into info.focus_position_um), each stamp
// the whole 21 x 21 frame.
std::vector<Stamp> SimulateStamps(const SimulationConfig& config, uint64_t noise_seed);

}  // namespace ccdpsf::testing_support

#endif  // CCDPSF_TESTS_SUPPORT_SIMULATED_STAMPS_H_
