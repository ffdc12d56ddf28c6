// Per-exposure metadata: what the tool must know about a file beyond its pixels, the places
// each value may come from, and a record of the place it did come from.
//
// Quantities. The name is at once the command-line flag, the manifest column, the key in
// FIT.json's "calibration" and the key of the keyword map:
//
//   name               unit / form          default keyword
//   gain_e_per_adu     e-/ADU               GAIN
//   read_noise_e       e-                   RDNOISE
//   bias_adu           ADU                  BIASLVL
//   bias_section       IRAF section         BIASSEC   overscan / prescan of the segment
//   data_section       IRAF section         DATASEC   light-sensitive pixels of the segment
//   saturation_adu     ADU                  SATURATE
//   pixel_um           um                   PIXSIZE
//   wavelength_nm      nm                   WAVELEN
//   exptime_s          s                    EXPTIME
//   focus_position_um  um                   FOCUSPOS  stage position, for focus series
//   spot_x_px          px (frame)           -         where the spot is (give both, or
//   spot_y_px          px (frame)           -         a search_region)
//   search_region      IRAF section         -         where to look for the spot
//   hdu                EXTNAME or number    -         which image: 0 = primary, 1 = first
//                                                     extension (astropy's and DS9's count)
//   bad_pixel_mask     FITS file            -         non-zero pixels are never fitted
//
// Precedence, highest first (exposure.h applies it):
//   1. a command-line flag (applies to every file of the run);
//   2. the file's row in a manifest (manifest.h);
//   3. FIT.json's "calibration" (applies to every file);
//   4. the header keyword, under the name the keyword map gives it;
//   5. an estimate from the pixels where one exists: bias and read noise from the bias
//      section or the background, the spot by spot finding, the segment by where the spot is;
//   6. nothing: the quantity is unknown. Where it is needed that is an error naming the ways
//      to give it (gain, pixel size), never a silent default. Quantities only some analyses
//      need (wavelength, exposure time, focus position) stay unknown and are reported so.
// Every value used is recorded with its source (CalibrationReport::metadata), and lands in
// fit.json, diagnose.json and trend's group tables.
#ifndef CCDPSF_METADATA_H_
#define CCDPSF_METADATA_H_

#include <limits>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/fits_io.h"
#include "nlohmann/json.hpp"

namespace ccdpsf {

// The quantity names above, in that order.
const std::vector<std::string>& MetadataQuantities();
bool IsNumericQuantity(const std::string& name);
bool IsMetadataQuantity(const std::string& name);
// Whether `value` is in the range of the numeric quantity (finite, a positive gain, pixel
// size and wavelength, a non-negative read noise and exposure time, and each within a
// bound no lab reaches, e.g. |bias| <= 1e12 ADU). False with a message that gives the
// range: "bias_adu must be finite and within [-1e+12, 1e+12], got 1e+300", "gain_e_per_adu
// must be positive and finite, got 0", "... must be at most 1e+06, got 2e+06". Text
// quantities: always true.
bool CheckQuantityValue(const std::string& quantity, double value, std::string* error);

// Where a header keyword is read from for one quantity: the keyword's name and the factor
// that converts its value to the quantity's unit (e.g. 1e-3 for an exposure time in ms).
struct KeywordRule {
  std::string keyword;
  double scale = 1.0;
};

// Quantity name -> keyword rule. Quantities without a rule are not read from headers.
class KeywordMap {
 public:
  // The default names of the table above.
  KeywordMap();

  const KeywordRule* Find(const std::string& quantity) const;
  const std::map<std::string, KeywordRule>& rules() const { return rules_; }

  // Overlays a lab's names. Accepts a JSON object {"gain_e_per_adu": "EGAIN",
  // "exptime_s": {"keyword": "EXPMS", "scale": 0.001}} or the text "gain_e_per_adu=EGAIN,
  // exptime_s=EXPMS*0.001". A keyword of "" (or "-") switches the quantity's keyword off.
  // False with a one-line reason on an unknown quantity, a malformed keyword name or scale.
  bool Overlay(const nlohmann::json& rules, std::string* error);
  bool OverlayText(const std::string& text, std::string* error);
  // --keywords=: a JSON file (if `text` names one) or the inline text form.
  bool OverlayFileOrText(const std::string& text, std::string* error);

  nlohmann::json ToJson() const;

 private:
  bool Set(const std::string& quantity, const KeywordRule& rule, std::string* error);
  std::map<std::string, KeywordRule> rules_;
};

// A value a user gave (flag, manifest, FIT.json) for one quantity, with its source, e.g.
// "flag --pixel_um" or "manifest runs.csv line 4".
struct GivenValue {
  std::optional<double> number;
  std::optional<std::string> text;
  std::string source;
  bool has() const { return number.has_value() || text.has_value(); }
};

// The values given for one file, by quantity name.
class GivenMetadata {
 public:
  bool Has(const std::string& quantity) const;
  const GivenValue* Find(const std::string& quantity) const;
  void SetNumber(const std::string& quantity, double value, const std::string& source);
  void SetText(const std::string& quantity, const std::string& value, const std::string& source);
  // Fills every quantity not given here from `lower` (a source of lower precedence).
  void FillFrom(const GivenMetadata& lower);
  // Parses one value from its text form (manifest cells, flags): numbers for the numeric
  // quantities, non-empty text for the others. False with a one-line reason.
  bool SetFromText(const std::string& quantity, const std::string& text,
                   const std::string& source, std::string* error);
  const std::map<std::string, GivenValue>& values() const { return values_; }

 private:
  std::map<std::string, GivenValue> values_;
};

// One quantity as used: its value (number or text; NaN / empty when unknown) and source.
struct MetadataEntry {
  double number = std::numeric_limits<double>::quiet_NaN();
  std::string text;
  std::string source;  // "unknown" when nothing gave it
};
using MetadataRecord = std::map<std::string, MetadataEntry>;
nlohmann::json MetadataRecordJson(const MetadataRecord& record);

// Resolves a numeric quantity: the given value, else the keyword (through the map, scaled),
// else empty. A keyword that is present but not a number is an error (a broken header must
// not pass for a missing one). *source names where the value came from.
bool ResolveNumber(const GivenMetadata& given, const KeywordMap& keywords,
                   const FitsHeader& header, const std::string& quantity,
                   std::optional<double>* value, std::string* source, std::string* error);
// The same for the text quantities (sections).
bool ResolveText(const GivenMetadata& given, const KeywordMap& keywords, const FitsHeader& header,
                 const std::string& quantity, std::optional<std::string>* value,
                 std::string* source, std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_METADATA_H_
