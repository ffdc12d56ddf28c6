#include "ccdpsf/column_units.h"

#include <cctype>
#include <utility>

namespace ccdpsf {

std::string UnitOfName(const std::string& name) {
  // An exposure index after a dot or a final underscore (x_px.3, x_px_3, flux_ratio_2) is not
  // part of the unit; an effect's parameter (serial_cti.trail_length_px) has it after the dot.
  std::string base = name;
  const std::size_t dot = name.rfind('.');
  if (dot != std::string::npos) {
    const std::string after = name.substr(dot + 1);
    const bool index = !after.empty() && after.find_first_not_of("0123456789") == std::string::npos;
    base = index ? name.substr(0, dot) : after;
  }
  // The bounds of a central 68 % interval (fwhm_um_lo68, fwhm_um_hi68) carry their
  // quantity's unit.
  for (const char* bound : {"_lo68", "_hi68"}) {
    const std::string b = bound;
    if (base.size() > b.size() && base.compare(base.size() - b.size(), b.size(), b) == 0) {
      base.resize(base.size() - b.size());
      break;
    }
  }
  const std::size_t last = base.find_last_of('_');
  if (last != std::string::npos && last + 1 < base.size() &&
      base.find_first_not_of("0123456789", last + 1) == std::string::npos) {
    base.resize(last);
  }
  // Longest suffixes first: _e_per_adu before _adu, _px_per_um before _um, _px2 before _px.
  static const std::pair<const char*, const char*> kSuffixes[] = {{"_e_per_adu", "electron/adu"},
                                                                  {"_px_per_e", "pix/electron"},
                                                                  {"_per_e", "1/electron"},
                                                                  {"_px_per_um", "pix/um"},
                                                                  {"_arcsec2", "arcsec2"},
                                                                  {"_adu2", "adu2"},
                                                                  {"_adu", "adu"},
                                                                  {"_px2", "pix2"},
                                                                  {"_um2", "um2"},
                                                                  {"_px", "pix"},
                                                                  {"_um", "um"},
                                                                  {"_nm", "nm"},
                                                                  {"_e", "electron"},
                                                                  {"_s", "s"}};
  for (const auto& [suffix, unit] : kSuffixes) {
    const std::string s = suffix;
    if (base.size() > s.size() && base.compare(base.size() - s.size(), s.size(), s) == 0) {
      return unit;
    }
  }
  return "";
}

std::string FitsColumnName(const std::string& name) {
  std::string out = name;
  for (char& c : out) {
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_')) c = '_';
  }
  return out;
}

}  // namespace ccdpsf
