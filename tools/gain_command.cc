// ccdpsf gain: the camera's gain [e-/ADU] and read noise [e-] from the frames a user has, by
// photon transfer (photon_transfer.h), for cameras whose headers record neither.
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/output_folder.h"
#include "ccdpsf/fits_io.h"
#include "ccdpsf/manifest.h"
#include "ccdpsf/photon_transfer.h"
#include "ccdpsf/provenance.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(out);
DECLARE_int32(max_image_mb);             // the reader's memory ceiling (input_flags.cc)
DEFINE_string(gain_method, "auto", "");  // meaning: GainCommand()'s table

namespace ccdpsf::tools {
namespace {

// Points are listed on screen up to this many; beyond, gain.csv has them.
constexpr int kMaxPointsOnScreen = 15;

// A number of the summary: "%.3g", or "-" when not finite.
std::string Show(double value, const char* format = "%.3g") {
  if (!std::isfinite(value)) return "-";
  char text[64];
  std::snprintf(text, sizeof(text), format, value);
  return text;
}

void PrintSummary(const PhotonTransferResult& r) {
  std::printf("ccdpsf gain: %zu frame(s), method %s", r.frames.size(), r.method.c_str());
  if (r.method == "pairs") {
    std::printf(" (%d pair(s) at equal exposure times)\n", r.pairs);
  } else {
    std::printf(" (differences within each frame)\n");
  }
  std::printf("  gain         %s +- %s e-/ADU\n", Show(r.gain_e_per_adu, "%.4g").c_str(),
              Show(r.gain_sd_e_per_adu, "%.2g").c_str());
  if (std::isfinite(r.read_noise_e)) {
    std::printf("  read noise   %s +- %s e-\n", Show(r.read_noise_e, "%.3g").c_str(),
                Show(r.read_noise_sd_e, "%.2g").c_str());
  } else if (std::isfinite(r.read_noise_upper_e)) {
    std::printf("  read noise   not determined; < %s e- (see the warnings)\n",
                Show(r.read_noise_upper_e).c_str());
  } else {
    std::printf("  read noise   not determined (see the warnings)\n");
  }
  if (std::isfinite(r.bias_adu)) {
    std::printf("  bias         %s ADU (%s)\n", Show(r.bias_adu, "%.5g").c_str(),
                r.bias_source.c_str());
  } else {
    std::printf("  bias         unknown\n");
  }
  std::printf(
      "  fit          variance = %s + mean / %s [ADU^2]; %d points from %s to %s ADU; "
      "chi2 %s / %d\n",
      Show(r.intercept_adu2, "%.4g").c_str(), Show(r.gain_e_per_adu, "%.4g").c_str(), r.points_used,
      Show(r.min_level_adu, "%.4g").c_str(), Show(r.max_level_adu, "%.4g").c_str(),
      Show(r.chi2, "%.3g").c_str(), r.dof);
  if (r.points_used <= kMaxPointsOnScreen) {
    std::printf("  points       mean [ADU]  variance [ADU^2]  pixels\n");
    for (const PtcPoint& p : r.points) {
      if (!p.used) continue;
      std::printf("               %10.4g  %16.4g  %6lld\n", p.mean_adu, p.variance_adu2, p.pixels);
    }
  }
  for (const std::string& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
}

int RunGain(const std::vector<std::string>& args) {
  if (args.empty() && !FlagGiven("manifest")) {
    return Usage("gain needs FITS files (or --manifest)");
  }
  if (FLAGS_max_image_mb < 1) return Fail("--max_image_mb must be at least 1");
  SetMaxImageBytes(static_cast<long long>(FLAGS_max_image_mb) << 20, kWholeImageBytesPerPixel);
  std::vector<std::string> files;
  PhotonTransferOptions options;
  std::string error;
  if (!ResolveTransferInputs(args, "the gain estimate", &files, &options, &error)) {
    return Fail(error);
  }
  if (!ParsePtcMethod(FLAGS_gain_method, &options.method)) {
    return Fail("--gain_method must be auto, pairs or single_frame (got '" + FLAGS_gain_method +
                "')");
  }
  if (!options.IsValid(&error)) return Fail(error);
  OutputFolder out;
  if (!FLAGS_out.empty() && !out.Begin(FLAGS_out, RunInputs(files), {}, &error)) {
    return Fail(error);
  }
  PhotonTransferResult result;
  if (!EstimatePhotonTransferFromFiles(files, options, &result, &error)) return Fail(error);
  PrintSummary(result);
  if (FLAGS_out.empty()) return 0;
  nlohmann::json json = PhotonTransferJson(result);
  if (!WriteTextFileAtomically(out.partial() + "/gain.json", json.dump(2) + "\n", &error) ||
      !WriteTextFileAtomically(out.partial() + "/gain.csv", PhotonTransferCsv(result), &error)) {
    return Fail(error);
  }
  nlohmann::json run_options = TransferRunOptions(files);
  run_options["gain_method"] = FLAGS_gain_method;
  run_options["out"] = FLAGS_out;
  // Nothing random is drawn: the seed recorded is 0.
  if (!WriteRunRecord(out.partial(), "gain", run_options, 0, &error) ||
      !out.Commit({}, &error)) {
    return Fail(error);
  }
  std::printf("wrote %s/gain.json and %s/gain.csv\n", FLAGS_out.c_str(), FLAGS_out.c_str());
  return 0;
}

}  // namespace

Command GainCommand() {
  std::vector<Option> options = TransferInputOptions();
  options.push_back({"gain_method", "auto",
                     "auto (pairs when two frames share an exposure time, else single_frame), "
                     "pairs or single_frame"});
  options.push_back(MaxImageMbOption());
  options.push_back({"out", "",
                     "Output folder for gain.json and gain.csv (not given: the summary on the "
                     "terminal only)"});
  return {"gain",
          "ccdpsf gain [--exptime_s=S] [--manifest=FILE] [--bias_adu=B] [--saturation_adu=S] "
          "[--gain_method=auto|pairs|single_frame] [--max_image_mb=MB] [--out=DIR] FILE.fits...",
          "Estimate the gain [e-/ADU] and read noise [e-] by photon transfer, from frame pairs "
          "at equal exposure times or from single frames.",
          options, RunGain};
}

}  // namespace ccdpsf::tools
