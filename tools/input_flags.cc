// The flags that say what a file's header lacks, shared by fit, diagnose and trend: one
// per metadata quantity (metadata.h), the keyword map, the manifest and the stamp size; and
// the reader's memory ceiling (also read by gain); and what the photon-transfer commands (gain,
// ptc) take from the manifest and these flags (ResolveTransferInputs).
#include <cmath>
#include <cstdio>
#include <limits>

#include "ccdpsf/fits_io.h"
#include "ccdpsf/manifest.h"
#include "ccdpsf/metadata.h"
#include "command.h"
#include "gflags/gflags.h"

// The parser's flags; what each means is InputOptions() below. 0 / "" = not given.
DEFINE_double(gain_e_per_adu, 0, "");
DEFINE_double(read_noise_e, 0, "");
DEFINE_double(bias_adu, 0, "");
DEFINE_string(bias_section, "", "");
DEFINE_string(data_section, "", "");
DEFINE_double(saturation_adu, 0, "");
DEFINE_double(pixel_um, 0, "");
DEFINE_double(wavelength_nm, 0, "");
DEFINE_double(exptime_s, 0, "");
DEFINE_double(focus_position_um, 0, "");
DEFINE_double(spot_x_px, 0, "");
DEFINE_double(spot_y_px, 0, "");
DEFINE_string(search_region, "", "");
DEFINE_string(hdu, "", "");
DEFINE_string(bad_pixel_mask, "", "");
DEFINE_string(keywords, "", "");
DEFINE_string(manifest, "", "");
DEFINE_int32(stamp_size, 21, "");
DEFINE_int32(max_image_mb, static_cast<int>(ccdpsf::kDefaultMaxImageBytes >> 20), "");

namespace ccdpsf::tools {

Option MaxImageMbOption() {
  return {"max_image_mb", std::to_string(kDefaultMaxImageBytes >> 20),
          "Most memory one image may take [MB = 2^20 bytes], at 18 bytes a pixel (the image, a "
          "smoothed copy, masks); larger images, and gzip files decompressing to more, are "
          "refused before reading"};
}

std::vector<Option> InputOptions() {
  // The metadata flags: each value applies to every file and outranks the manifest and the
  // header (metadata.h).
  std::vector<Option> o = {
      {"gain_e_per_adu", "0", "Gain [e-/ADU]; overrides the manifest and GAIN", true},
      {"read_noise_e", "0", "Read noise [e-]; overrides the manifest and RDNOISE", true},
      {"bias_adu", "0", "Bias level [ADU]; overrides the manifest, BIASLVL and the bias section",
       true},
      {"bias_section", "",
       "Overscan / prescan as an IRAF section, e.g. [1:20,1:2048] (1-based, inclusive); "
       "overrides the manifest and BIASSEC",
       true},
      {"data_section", "",
       "Light-sensitive pixels of the image as an IRAF section; overrides DATASEC", true},
      {"saturation_adu", "0",
       "Saturation level [ADU]: pixels at or above it are fitted as censored; overrides the "
       "manifest and SATURATE",
       true},
      {"pixel_um", "0",
       "Pixel pitch [um]; overrides the manifest and PIXSIZE (required from one of them)", true},
      {"wavelength_nm", "0", "Wavelength [nm]; overrides the manifest and WAVELEN", true},
      {"exptime_s", "0", "Exposure time [s]; overrides the manifest and EXPTIME", true},
      {"focus_position_um", "0", "Stage focus position [um]; overrides FOCUSPOS", true},
      {"spot_x_px", "0", "Spot x [frame pixels, 0-based]; with --spot_y_px skips spot finding",
       true},
      {"spot_y_px", "0", "Spot y [frame pixels, 0-based]", true},
      {"search_region", "", "Look for the spot only in this IRAF section, e.g. [600:700,420:520]",
       true},
      {"hdu", "",
       "Image to read: extension number (0 = primary, 1 = first extension) or EXTNAME; when not "
       "given: the primary image, or for a multi-extension file the segment holding the spot",
       true},
      {"bad_pixel_mask", "",
       "FITS image of the frame's size whose non-zero pixels are never fitted", true},
      {"keywords", "",
       "Keyword map for another lab's headers: a JSON file, or "
       "quantity=KEYWORD[*scale],... e.g. gain_e_per_adu=EGAIN,exptime_s=EXPMS*0.001",
       true},
      {"manifest", "",
       "CSV or JSON file with one row per FITS file giving what its header lacks (columns: "
       "file, setting, and any quantity above)",
       true},
      {"stamp_size", std::to_string(CalibrationOptions().stamp_size), "Stamp side [px]"},
      MaxImageMbOption()};
  return o;
}

bool InputFlags(GivenMetadata* given, KeywordMap* keywords, std::string* error) {
  if (FLAGS_max_image_mb < 1) {
    *error = "--max_image_mb must be at least 1";
    return false;
  }
  SetMaxImageBytes(static_cast<long long>(FLAGS_max_image_mb) << 20, kWholeImageBytesPerPixel);
  struct NumberFlag {
    const char* name;
    double value;
  };
  const NumberFlag numbers[] = {{"gain_e_per_adu", FLAGS_gain_e_per_adu},
                                {"read_noise_e", FLAGS_read_noise_e},
                                {"bias_adu", FLAGS_bias_adu},
                                {"saturation_adu", FLAGS_saturation_adu},
                                {"pixel_um", FLAGS_pixel_um},
                                {"wavelength_nm", FLAGS_wavelength_nm},
                                {"exptime_s", FLAGS_exptime_s},
                                {"focus_position_um", FLAGS_focus_position_um},
                                {"spot_x_px", FLAGS_spot_x_px},
                                {"spot_y_px", FLAGS_spot_y_px}};
  for (const NumberFlag& f : numbers) {
    if (!FlagGiven(f.name)) continue;
    if (!std::isfinite(f.value)) {
      *error = std::string("--") + f.name + " must be a finite number";
      return false;
    }
    given->SetNumber(f.name, f.value, std::string("flag --") + f.name);
  }
  struct TextFlag {
    const char* name;
    const std::string& value;
  };
  const TextFlag texts[] = {{"bias_section", FLAGS_bias_section},
                            {"data_section", FLAGS_data_section},
                            {"search_region", FLAGS_search_region},
                            {"hdu", FLAGS_hdu},
                            {"bad_pixel_mask", FLAGS_bad_pixel_mask}};
  for (const TextFlag& f : texts) {
    if (!FlagGiven(f.name)) continue;
    if (!given->SetFromText(f.name, f.value, std::string("flag --") + f.name, error)) {
      *error = "--" + *error;
      return false;
    }
  }
  if (FlagGiven("keywords") && !keywords->OverlayFileOrText(FLAGS_keywords, error)) return false;
  return true;
}

bool ResolveInputs(const std::vector<std::string>& files, const CalibrationOptions& config,
                   std::vector<InputFile>* inputs, Manifest* manifest, std::string* error) {
  GivenMetadata flags;
  CalibrationOptions merged = config;
  if (!InputFlags(&flags, &merged.keywords, error)) return false;
  const Manifest* m = nullptr;
  if (FlagGiven("manifest")) {
    if (!LoadManifest(FLAGS_manifest, manifest, error)) return false;
    m = manifest;
  }
  if (!ResolveInputFiles(files, m, flags, merged, inputs, error)) return false;
  for (const InputFile& input : *inputs) {
    if (!input.options.IsValid(error)) {
      *error = "'" + input.path + "': " + *error;
      return false;
    }
  }
  return true;
}

std::vector<std::string> RunInputs(const std::vector<std::string>& args) {
  std::vector<std::string> inputs = args;
  for (const char* flag : {"config", "manifest", "keywords", "bad_pixel_mask", "requirements"}) {
    std::string value;
    if (gflags::GetCommandLineOption(flag, &value) && !value.empty()) inputs.push_back(value);
  }
  return inputs;
}

namespace {

// A number of a message: "%.3g", or "-" when not finite.
std::string ShowNumber(double value) {
  if (!std::isfinite(value)) return "-";
  char text[64];
  std::snprintf(text, sizeof(text), "%.3g", value);
  return text;
}

}  // namespace

nlohmann::json TransferRunOptions(const std::vector<std::string>& files) {
  auto given = [](const char* name, double value) {
    return FlagGiven(name) ? nlohmann::json(value) : nlohmann::json();
  };
  return {{"files", files},
          {"exptime_s", given("exptime_s", FLAGS_exptime_s)},
          {"bias_adu", given("bias_adu", FLAGS_bias_adu)},
          {"saturation_adu", given("saturation_adu", FLAGS_saturation_adu)},
          {"manifest", FLAGS_manifest}};
}

std::vector<Option> TransferInputOptions() {
  return {{"exptime_s", "0",
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
           true}};
}

bool ResolveTransferInputs(const std::vector<std::string>& args, const std::string& purpose,
                           std::vector<std::string>* files, TransferFrameOptions* options,
                           std::string* error) {
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
    if (row == nullptr) return std::numeric_limits<double>::quiet_NaN();
    const GivenValue* v = row->values.Find(quantity);
    if (v == nullptr || !v->number) return std::numeric_limits<double>::quiet_NaN();
    *source = v->source;
    return *v->number;
  };

  // Exposure times: the flag for every file, else each file's manifest row, else (NaN) the
  // file's EXPTIME keyword.
  for (const ManifestRow* row : rows) {
    std::string source = "flag --exptime_s";
    double t = std::numeric_limits<double>::quiet_NaN();
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
                 ShowNumber(*value) + " and " + ShowNumber(v) + "); " + purpose + " needs one";
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
  return true;
}

}  // namespace ccdpsf::tools
