// ccdpsf ptc: the gain [e-/ADU], read noise [e-] and boundary-shift coefficients a_ij [1/e-]
// of a CCD from flat-field pairs, by photon transfer with pixel covariances (ptc.h).
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "ccdpsf/atomic_file.h"
#include "ccdpsf/fits_io.h"
#include "ccdpsf/output_folder.h"
#include "ccdpsf/plot.h"
#include "ccdpsf/provenance.h"
#include "ccdpsf/ptc.h"
#include "ccdpsf/ptc_report.h"
#include "command.h"
#include "gflags/gflags.h"

DECLARE_string(out);
DECLARE_string(plot_format);
DECLARE_int32(max_image_mb);
DEFINE_int32(max_lag, 3, "");       // meaning: PtcCommand()'s table
DEFINE_string(ptc_model, "a", "");  // meaning: PtcCommand()'s table

namespace ccdpsf::tools {
namespace {

// "%.4g" of a value, or "-".
std::string Show(double value, const char* format = "%.4g") {
  if (!std::isfinite(value)) return "-";
  char text[64];
  std::snprintf(text, sizeof(text), format, value);
  return text;
}

void PrintSummary(const PtcResult& r) {
  std::printf(
      "ccdpsf ptc: %d flat pair(s) used of %zu, levels %s to %s ADU, model %s, lags "
      "0..%d\n",
      r.pairs_used, r.pairs.size(), Show(r.min_level_adu).c_str(), Show(r.max_level_adu).c_str(),
      PtcModelName(r.model), r.max_lag);
  std::printf("  gain         %s +- %s e-/ADU\n", Show(r.gain_e_per_adu.value, "%.5g").c_str(),
              Show(r.gain_e_per_adu.sd, "%.2g").c_str());
  if (std::isfinite(r.read_noise_e.value)) {
    std::printf("  read noise   %s +- %s e-\n", Show(r.read_noise_e.value).c_str(),
                Show(r.read_noise_e.sd, "%.2g").c_str());
  } else {
    std::printf("  read noise   not significant; < %s e- (2 sd)\n",
                Show(r.read_noise_upper_e).c_str());
  }
  std::printf("  bias         %s ADU (%s)\n", Show(r.bias_adu, "%.6g").c_str(),
              r.bias_source.c_str());
  const int side = r.max_lag + 1;
  for (const auto& [i, j] : std::vector<std::pair<int, int>>{{0, 0}, {1, 0}, {0, 1}, {1, 1}}) {
    const int l = j * side + i;
    std::printf("  a_%s         %s +- %s per e-\n", r.lag_names[l].c_str(),
                Show(r.a[l].value).c_str(), Show(r.a[l].sd, "%.2g").c_str());
  }
  std::printf("  fit          chi2 %s for %d dof\n", Show(r.chi2, "%.5g").c_str(), r.dof);
  for (const std::string& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
}

int RunPtc(const std::vector<std::string>& args) {
  if (args.empty() && !FlagGiven("manifest")) {
    return Usage("ptc needs flat-field FITS files (or --manifest)");
  }
  if (FLAGS_out.empty()) return Usage("ptc needs --out=DIR");
  if (FLAGS_max_image_mb < 1) return Fail("--max_image_mb must be at least 1");
  SetMaxImageBytes(static_cast<long long>(FLAGS_max_image_mb) << 20, kWholeImageBytesPerPixel);
  std::vector<std::string> files;
  PtcOptions options;
  std::string error;
  if (!ResolveTransferInputs(args, "the ptc analysis", &files, &options, &error)) {
    return Fail(error);
  }
  if (!ParsePtcModel(FLAGS_ptc_model, &options.model)) {
    return Fail("--ptc_model must be a or ab (got '" + FLAGS_ptc_model + "')");
  }
  options.max_lag = FLAGS_max_lag;
  if (!options.IsValid(&error)) return Fail("--max_lag: " + error);
  PlotOptions plot;
  if (!ParsePlotFormat(FLAGS_plot_format, &plot.format, &error)) return Fail(error);
  OutputFolder out;
  if (!out.Begin(FLAGS_out, RunInputs(files), {}, &error)) return Fail(error);

  PtcResult result;
  if (!EstimatePtcFromFiles(files, options, &result, &error)) return Fail(error);
  PrintSummary(result);
  std::vector<std::string> warnings;
  if (!WritePtcReport(out.partial(), result, plot, &warnings, &error)) return Fail(error);
  for (const std::string& w : warnings) std::printf("  warning: %s\n", w.c_str());
  nlohmann::json run_options = TransferRunOptions(files);
  run_options["max_lag"] = FLAGS_max_lag;
  run_options["ptc_model"] = FLAGS_ptc_model;
  run_options["plot_format"] = FLAGS_plot_format;
  run_options["out"] = FLAGS_out;
  // Nothing random is drawn: the seed recorded is 0.
  if (!WriteTextFileAtomically(out.partial() + "/ptc.csv", PtcCsv(result), &error) ||
      !WriteTextFileAtomically(out.partial() + "/ptc.json", PtcJson(result).dump(2) + "\n",
                               &error) ||
      !WriteRunRecord(out.partial(), "ptc", run_options, 0, &error) || !out.Commit({}, &error)) {
    return Fail(error);
  }
  std::printf("wrote %s/ptc.json, ptc.csv, report.md and plots\n", FLAGS_out.c_str());
  return 0;
}

}  // namespace

Command PtcCommand() {
  std::vector<Option> options = TransferInputOptions();
  options.push_back({"max_lag", "3",
                     "Largest lag L [px]: the covariances and a_ij at lags 0 <= i, j <= L "
                     "(1..8)"});
  options.push_back({"ptc_model", "a",
                     "a (boundary shifts in proportion to the charge: b_ij = 0) or ab (Astier "
                     "et al.'s b_ij fitted too)"});
  options.push_back({"plot_format", "png", "Format of the plots: png, pdf or svg"});
  options.push_back(MaxImageMbOption());
  options.push_back({"out", "", "Output folder for ptc.json, ptc.csv, report.md and the plots"});
  return {"ptc",
          "ccdpsf ptc --out=DIR [--exptime_s=S] [--manifest=FILE] [--bias_adu=B] "
          "[--saturation_adu=S] [--max_lag=L] [--ptc_model=a|ab] [--plot_format=png|pdf|svg] "
          "[--max_image_mb=MB] FLAT.fits...",
          "Gain, read noise and the boundary-shift (brighter-fatter) coefficients a_ij from "
          "flat-field pairs at several levels: photon transfer with pixel covariances (Astier "
          "et al. 2019).",
          options, RunPtc};
}

}  // namespace ccdpsf::tools
