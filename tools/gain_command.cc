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

DECLARE_double(exptime_s);
DECLARE_double(bias_adu);
DECLARE_double(saturation_adu);
DECLARE_string(manifest);
DECLARE_string(out);
DECLARE_int32(max_image_mb);  // the reader's memory ceiling (input_flags.cc)
DEFINE_string(gain_method, "auto", "");  // meaning: GainCommand()'s table

namespace ccdpsf::tools {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Points are listed on screen up to this many; beyond, gain.csv has them.
constexpr int kMaxPointsOnScreen = 15;

// A number of the summary: "%.3g", or "-" when not finite.
std::string Show(double value, const char* format = "%.3g") {
  if (!std::isfinite(value)) return "-";
  char text[64];
  std::snprintf(text, sizeof(text), format, value);
  return text;
}

// The run's files and what the manifest and flags say of them. False with a one-line reason.
bool ResolveGainInputs(const std::vector<std::string>& args, std::vector<std::string>* files,
                       PhotonTransferOptions* options, std::string* error) {
  Manifest manifest;
  const bool has_manifest = FlagGiven("manifest");
  if (has_manifest && !LoadManifest(FLAGS_manifest, &manifest, error)) return false;
  std::vector<const ManifestRow*> rows;
  if (args.empty()) {
    for (const ManifestRow& row : manifest.rows) {
      files->push_back(row.file);
      rows.push_back(&row);
    }
  } else {
    for (const std::string& file : args) {
      const ManifestRow* row = has_manifest ? manifest.Find(file) : nullptr;
      if (has_manifest && row == nullptr) {
        *error = "'" + file + "' is not listed in the manifest '" + FLAGS_manifest + "'";
        return false;
      }
      files->push_back(file);
      rows.push_back(row);
    }
  }
  if (files->empty()) {
    *error = "the manifest '" + FLAGS_manifest + "' lists no files";
    return false;
  }
  auto row_number = [](const ManifestRow* row, const char* quantity,
                       std::string* source) -> double {
    if (row == nullptr) return kNaN;
    const GivenValue* v = row->values.Find(quantity);
    if (v == nullptr || !v->number) return kNaN;
    *source = v->source;
    return *v->number;
  };

  // Exposure times: the flag for every file, else each file's manifest row, else (NaN) the
  // file's EXPTIME keyword.
  for (const ManifestRow* row : rows) {
    std::string source = "flag --exptime_s";
    double t = kNaN;
    if (FlagGiven("exptime_s")) {
      t = FLAGS_exptime_s;
    } else {
      t = row_number(row, "exptime_s", &source);
    }
    // NaN stands for "unknown" here (then EXPTIME is read), so a value given as NaN is
    // refused first: it is not unknown, it is wrong.
    if ((FlagGiven("exptime_s") || !std::isnan(t)) && !CheckQuantityValue("exptime_s", t, error)) {
      *error += " (" + source + ")";
      return false;
    }
    options->exptime_s.push_back(t);
    options->exptime_sources.push_back(std::isfinite(t) ? source : "unknown");
    // Frames pair only within a manifest setting (the same scene).
    options->scene.push_back(row != nullptr ? row->setting : std::string());
  }

  // Bias and saturation: one value for the set, from the flag or the manifest's rows (which
  // must then agree: the fit has one intercept).
  auto one_value = [&](const char* quantity, bool flag_given, double flag_value, double* value,
                       std::string* source) {
    if (flag_given) {
      *value = flag_value;
      *source = std::string("flag --") + quantity;
      if (!CheckQuantityValue(quantity, flag_value, error)) {
        *error += " (" + *source + ")";
        return false;
      }
      return true;
    }
    for (const ManifestRow* row : rows) {
      std::string s;
      const double v = row_number(row, quantity, &s);
      if (std::isnan(v)) continue;
      if (!CheckQuantityValue(quantity, v, error)) {
        *error += " (" + s + ")";
        return false;
      }
      if (std::isfinite(*value) && v != *value) {
        *error = std::string("the manifest gives different values of ") + quantity + " (" +
                 Show(*value) + " and " + Show(v) + "); the gain estimate needs one";
        return false;
      }
      *value = v;
      *source = s;
    }
    return true;
  };
  std::string saturation_source;
  if (!one_value("bias_adu", FlagGiven("bias_adu"), FLAGS_bias_adu, &options->bias_adu,
                 &options->bias_source) ||
      !one_value("saturation_adu", FlagGiven("saturation_adu"), FLAGS_saturation_adu,
                 &options->saturation_adu, &saturation_source)) {
    return false;
  }
  if (!ParsePtcMethod(FLAGS_gain_method, &options->method)) {
    *error = "--gain_method must be auto, pairs or single_frame (got '" + FLAGS_gain_method + "')";
    return false;
  }
  return options->IsValid(error);
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
  SetMaxImageBytes(static_cast<long long>(FLAGS_max_image_mb) << 20);
  std::vector<std::string> files;
  PhotonTransferOptions options;
  std::string error;
  if (!ResolveGainInputs(args, &files, &options, &error)) return Fail(error);
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
  const nlohmann::json run_options = {
      {"files", files},
      {"exptime_s", FlagGiven("exptime_s") ? nlohmann::json(FLAGS_exptime_s) : nlohmann::json()},
      {"bias_adu", FlagGiven("bias_adu") ? nlohmann::json(FLAGS_bias_adu) : nlohmann::json()},
      {"saturation_adu",
       FlagGiven("saturation_adu") ? nlohmann::json(FLAGS_saturation_adu) : nlohmann::json()},
      {"manifest", FLAGS_manifest},
      {"gain_method", FLAGS_gain_method},
      {"out", FLAGS_out}};
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
  return {"gain",
          "ccdpsf gain [--exptime_s=S] [--manifest=FILE] [--bias_adu=B] [--saturation_adu=S] "
          "[--gain_method=auto|pairs|single_frame] [--max_image_mb=MB] [--out=DIR] FILE.fits...",
          "Estimate the gain [e-/ADU] and read noise [e-] by photon transfer, from frame pairs "
          "at equal exposure times or from single frames.",
          {{"exptime_s", "0",
            "Exposure time [s] of every frame; overrides the manifest and EXPTIME (frames at "
            "one exposure time are paired)",
            true},
           {"manifest", "",
            "CSV or JSON file with one row per frame (columns: file, and exptime_s, bias_adu, "
            "saturation_adu where the headers lack them); no files given: every file it lists",
            true},
           {"bias_adu", "0",
            "Bias level [ADU] of every frame; overrides the manifest and BIASLVL (else from the "
            "overscan or the frame)",
            true},
           {"saturation_adu", "0",
            "Saturation level [ADU]: pixels at or above it are left out; overrides the manifest "
            "and SATURATE",
            true},
           {"gain_method", "auto",
            "auto (pairs when two frames share an exposure time, else single_frame), pairs or "
            "single_frame"},
           {"max_image_mb", std::to_string(kDefaultMaxImageBytes >> 20),
            "Largest image to read [MB = 2^20 bytes], as doubles (8 bytes a pixel); larger "
            "images, and gzip files decompressing to more, are refused before reading"},
           {"out", "",
            "Output folder for gain.json and gain.csv (not given: the summary on the terminal "
            "only)"}},
          RunGain};
}

}  // namespace ccdpsf::tools
