// Units carried in names, and names FITS readers accept.
//
// Every quantity ccdpsf writes names its unit in a suffix (fwhm_um, r2_px2, peak_e, ...), so a
// CSV column or a JSON key says what it holds. FITS tables want the unit in TUNITn, and column
// names (TTYPEn) made of letters, digits and underscores only (the FITS standard recommends
// it; fitsverify warns otherwise, and astropy / TOPCAT treat other characters unevenly).
#ifndef CCDPSF_COLUMN_UNITS_H_
#define CCDPSF_COLUMN_UNITS_H_

#include <string>

namespace ccdpsf {

// The FITS / VOUnit string for the unit suffix of `name` ("" when dimensionless or unknown):
// _px -> "pix", _px2 -> "pix2", _um -> "um", _um2 -> "um2", _nm -> "nm", _e -> "electron",
// _s -> "s", _adu -> "adu", _adu2 -> "adu2", _arcsec2 -> "arcsec2", _e_per_adu ->
// "electron/adu", _px_per_um -> "pix/um"; an exposure index after a dot or a final
// underscore is ignored (x_px.3, x_px_3 -> "pix"), and so is the suffix of an interval's
// bound (fwhm_um_lo68, fwhm_um_hi68 -> "um").
std::string UnitOfName(const std::string& name);

// `name` with every character outside [A-Za-z0-9_] replaced by '_' (x_px.3 -> x_px_3).
std::string FitsColumnName(const std::string& name);

}  // namespace ccdpsf

#endif  // CCDPSF_COLUMN_UNITS_H_
