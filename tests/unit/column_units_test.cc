#include "ccdpsf/column_units.h"

#include "gtest/gtest.h"

namespace ccdpsf {
namespace {

// The suffixes the tool's names use, each with the unit a reader should attach.
TEST(ColumnUnits, UnitFromTheNamesSuffix) {
  EXPECT_EQ(UnitOfName("ccd_sigma_x_px"), "pix");
  EXPECT_EQ(UnitOfName("x_px.3"), "pix");  // an exposure index is not part of the unit
  EXPECT_EQ(UnitOfName("x_px_3"), "pix");  // ... and so is one after a final '_'
  EXPECT_EQ(UnitOfName("r2_px2"), "pix2");
  EXPECT_EQ(UnitOfName("r2_arcsec2"), "arcsec2");
  EXPECT_EQ(UnitOfName("fwhm_um"), "um");
  EXPECT_EQ(UnitOfName("best_focus_um"), "um");
  EXPECT_EQ(UnitOfName("wavelength_nm"), "nm");
  EXPECT_EQ(UnitOfName("flux_e"), "electron");
  EXPECT_EQ(UnitOfName("exptime_s"), "s");
  EXPECT_EQ(UnitOfName("bias_adu"), "adu");
  EXPECT_EQ(UnitOfName("variance_adu2"), "adu2");
  EXPECT_EQ(UnitOfName("gain_e_per_adu"), "electron/adu");
  EXPECT_EQ(UnitOfName("defocus_rate_px_per_um"), "pix/um");
  // A fitted effect's parameter: the unit is the parameter's, after the dot.
  EXPECT_EQ(UnitOfName("serial_cti.trail_length_px"), "pix");
  EXPECT_EQ(UnitOfName("serial_cti.trail_fraction"), "");
  EXPECT_EQ(UnitOfName("brighter_fatter.slope_x_px_per_e"), "pix/electron");
  EXPECT_EQ(UnitOfName("nonlinearity.beta_per_e"), "1/electron");
  EXPECT_EQ(UnitOfName("background.pedestal_e"), "electron");
  // An interval's bounds carry the quantity's unit.
  EXPECT_EQ(UnitOfName("total_fwhm_um_lo68"), "um");
  EXPECT_EQ(UnitOfName("serial_cti_trail_length_px_hi68"), "pix");
  EXPECT_EQ(UnitOfName("ellipticity_lo68"), "");
  for (const char* dimensionless : {"ellipticity", "log_prob", "flux_ratio.2", "flux_ratio_2",
                                    "chi2_per_dof", "exposures", "focus_series", "e", "_px"}) {
    EXPECT_EQ(UnitOfName(dimensionless), "") << dimensionless;
  }
}

TEST(ColumnUnits, FitsColumnNamesKeepOnlyLettersDigitsAndUnderscores) {
  EXPECT_EQ(FitsColumnName("x_px.0"), "x_px_0");
  EXPECT_EQ(FitsColumnName("halo.fraction"), "halo_fraction");
  EXPECT_EQ(FitsColumnName("fwhm_um"), "fwhm_um");
  EXPECT_EQ(FitsColumnName("a-b c\xc3\xa9"), "a_b_c__");
}

}  // namespace
}  // namespace ccdpsf
