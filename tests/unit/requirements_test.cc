// Requirement checks on hand-made relations whose draws are known exactly, so value,
// interval, margin, pass and pass probability are checked against numbers worked out by
// hand; missing inputs; the strict JSON configuration.
#include "ccdpsf/trend/requirements.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include "gtest/gtest.h"

namespace ccdpsf::trend {
namespace {

// 100 draws m + step (k - 49.5), k = 0..99: median m exactly, symmetric about it.
std::vector<double> Ladder(double m, double step) {
  std::vector<double> v;
  for (int k = 0; k < 100; ++k) v.push_back(m + step * (k - 49.5));
  return v;
}

Coefficient MakeCoefficient(const std::string& name, std::vector<double> draws) {
  Coefficient c;
  c.name = name;
  c.estimate = SummarizeDraws(draws);
  c.draws = std::move(draws);
  return c;
}

// A fitted power law with the given draws of X(800 nm) and alpha (a follows from them).
RelationFit HandPowerLaw(std::vector<double> at_800, std::vector<double> alpha) {
  RelationFit f;
  f.kind = RelationKind::kPowerLaw;
  f.pivot = 800.0;
  f.fitted = true;
  f.dof = 3;
  std::vector<double> a(at_800.size());
  for (size_t r = 0; r < a.size(); ++r) a[r] = at_800[r] * std::pow(800.0, -alpha[r]);
  f.coefficients = {MakeCoefficient("a", a), MakeCoefficient("alpha", alpha),
                    MakeCoefficient("value_at_pivot", at_800)};
  for (double x : {600.0, 700.0, 800.0, 890.0}) {
    PointSummary p;
    p.abscissa = x;
    f.points.push_back(p);
  }
  return f;
}

RelationFit HandLinear(double intercept, double slope) {
  RelationFit f;
  f.kind = RelationKind::kLinear;
  f.pivot = kReferenceIntensityE;
  f.fitted = true;
  f.dof = 2;
  const std::vector<double> at_pivot(100, intercept + slope * kReferenceIntensityE);
  f.coefficients = {MakeCoefficient("intercept", std::vector<double>(100, intercept)),
                    MakeCoefficient("slope", std::vector<double>(100, slope)),
                    MakeCoefficient("value_at_pivot", at_pivot)};
  for (double x : {1.0e4, 1.6e5}) {
    PointSummary p;
    p.abscissa = x;
    f.points.push_back(p);
  }
  return f;
}

const RequirementResult& ByName(const std::vector<RequirementResult>& results,
                                const std::string& name) {
  for (const RequirementResult& r : results) {
    if (r.requirement.name == name) return r;
  }
  ADD_FAILURE() << "no requirement " << name;
  static const RequirementResult none;
  return none;
}

TEST(Requirements, DefaultsAreTheEuclidVisOnes) {
  const std::vector<Requirement> d = DefaultRequirements();
  ASSERT_EQ(d.size(), 3u);
  EXPECT_EQ(d[0].metric, "fwhm_um");
  EXPECT_EQ(d[0].limit, 10.8);
  EXPECT_EQ(d[0].wavelength_nm, 800.0);
  EXPECT_EQ(d[0].intensity_e, 157800.0);
  EXPECT_EQ(d[1].metric, "ellipticity");
  EXPECT_EQ(d[1].limit, 0.156);
  EXPECT_EQ(d[2].relation, "fwhm_um_vs_wavelength");
  EXPECT_EQ(d[2].coefficient, "alpha");
  EXPECT_EQ(d[2].limit, -0.2);
  for (const Requirement& r : d) {
    EXPECT_EQ(r.comparison, Comparison::kAtMost);
    std::string error;
    EXPECT_TRUE(r.IsValid(&error)) << error;
  }
}

// With the x and y FWHM relations present, the ellipticity at (800 nm, I0) is computed from
// them draw by draw, e_r = |x_r^2 - y_r^2| / (x_r^2 + y_r^2), and the e relation (here 0.175,
// far off) is not used. Expected: the same formula evaluated here on the ladders; its median
// by sorting (100 draws: mean of the 50th and 51st).
TEST(Requirements, EllipticityFollowsFromTheXAndYLaws) {
  std::map<std::string, RelationFit> relations;
  const std::vector<double> x = Ladder(8.40, 0.002), y = Ladder(8.50, 0.001);
  relations["fwhm_x_um_vs_wavelength"] = HandPowerLaw(x, std::vector<double>(100, -0.24));
  relations["fwhm_y_um_vs_wavelength"] = HandPowerLaw(y, std::vector<double>(100, -0.31));
  relations["ellipticity_vs_wavelength"] =
      HandPowerLaw(Ladder(0.175, 0.0005), std::vector<double>(100, -0.15));
  std::vector<double> e;
  for (size_t r = 0; r < 100; ++r) {
    e.push_back(std::fabs(x[r] * x[r] - y[r] * y[r]) / (x[r] * x[r] + y[r] * y[r]));
  }
  std::sort(e.begin(), e.end());
  const std::vector<RequirementResult> results =
      EvaluateRequirements(DefaultRequirements(), relations);
  const RequirementResult& got = ByName(results, "ellipticity_800nm");
  ASSERT_TRUE(got.pass.has_value()) << got.reason;
  EXPECT_NEAR(got.value.median, 0.5 * (e[49] + e[50]), 1e-14);
  EXPECT_EQ(got.pass_probability, 1.0);
  ASSERT_FALSE(got.notes.empty());
  EXPECT_NE(got.notes.back().find("fwhm_x_um and fwhm_y_um"), std::string::npos);
}

TEST(Requirements, PassFailAndMarginsByHand) {
  std::map<std::string, RelationFit> relations;
  // FWHM(800 nm) draws 8.305 .. 9.295, median 8.8; alpha -0.2595 .. -0.1605, median -0.21:
  // 60 of the 100 alpha draws are <= -0.2.
  relations["fwhm_um_vs_wavelength"] = HandPowerLaw(Ladder(8.8, 0.01), Ladder(-0.21, 0.001));
  // Ellipticity at 800 nm 0.1505 .. 0.1995 (median 0.175: fails 0.156); 12 draws pass
  // (0.175 + 0.0005 (k - 49.5) <= 0.156  <=>  k <= 11.5: k = 0..11, 12 draws pass).
  relations["ellipticity_vs_wavelength"] = HandPowerLaw(Ladder(0.175, 0.0005),
                                                        std::vector<double>(100, -0.15));
  const std::vector<RequirementResult> results =
      EvaluateRequirements(DefaultRequirements(), relations);
  ASSERT_EQ(results.size(), 3u);

  const RequirementResult& fwhm = ByName(results, "fwhm_800nm");
  ASSERT_TRUE(fwhm.pass.has_value()) << fwhm.reason;
  EXPECT_TRUE(*fwhm.pass);
  EXPECT_NEAR(fwhm.value.median, 8.8, 1e-12);
  EXPECT_NEAR(fwhm.margin, 2.0, 1e-12);
  EXPECT_EQ(fwhm.pass_probability, 1.0);
  EXPECT_EQ(Verdict(fwhm), "pass");
  // 15.87th percentile of the ladder: position 0.158655 * 99 = 15.707 -> 8.8 + 0.01 * (15.707
  // - 49.5).
  EXPECT_NEAR(fwhm.value.lo68, 8.8 + 0.01 * (0.158655 * 99 - 49.5), 1e-12);

  const RequirementResult& e = ByName(results, "ellipticity_800nm");
  ASSERT_TRUE(e.pass.has_value()) << e.reason;
  EXPECT_FALSE(*e.pass);
  EXPECT_NEAR(e.margin, 0.156 - 0.175, 1e-12);
  EXPECT_NEAR(e.pass_probability, 0.12, 1e-12);
  EXPECT_EQ(Verdict(e), "undetermined");  // fails by the median, but 12 % of draws pass

  const RequirementResult& alpha = ByName(results, "alpha_fwhm");
  ASSERT_TRUE(alpha.pass.has_value()) << alpha.reason;
  EXPECT_TRUE(*alpha.pass);
  EXPECT_NEAR(alpha.value.median, -0.21, 1e-12);
  EXPECT_NEAR(alpha.margin, 0.01, 1e-12);
  EXPECT_NEAR(alpha.pass_probability, 0.60, 1e-12);
  EXPECT_EQ(Verdict(alpha), "undetermined");  // passes by the median only

  // A lower limit: margin value - limit, positive when passing.
  Requirement min_alpha = DefaultRequirements()[2];
  min_alpha.name = "alpha_at_least";
  min_alpha.comparison = Comparison::kAtLeast;
  min_alpha.limit = -0.25;
  const RequirementResult lower = EvaluateRequirements({min_alpha}, relations)[0];
  ASSERT_TRUE(lower.pass.has_value());
  EXPECT_TRUE(*lower.pass);
  EXPECT_NEAR(lower.margin, 0.04, 1e-12);
  // -0.21 + 0.001 (k - 49.5) >= -0.25  <=>  k >= 9.5: 90 draws.
  EXPECT_NEAR(lower.pass_probability, 0.90, 1e-12);
  EXPECT_EQ(Verdict(lower), "undetermined");
  // Settled either way at P(pass) 0.05 and 0.95: draw k is -0.21 + 0.001 (k - 49.5), so
  // alpha >= -0.165 holds for k >= 95 (5 draws) and alpha >= -0.255 for k >= 5 (95 draws).
  min_alpha.limit = -0.165;
  const RequirementResult failing = EvaluateRequirements({min_alpha}, relations)[0];
  EXPECT_NEAR(failing.pass_probability, 0.05, 1e-12);
  EXPECT_EQ(Verdict(failing), "fail");
  min_alpha.limit = -0.255;
  const RequirementResult passing = EvaluateRequirements({min_alpha}, relations)[0];
  EXPECT_NEAR(passing.pass_probability, 0.95, 1e-12);
  EXPECT_EQ(Verdict(passing), "pass");

  const nlohmann::json j = ToJson(fwhm);
  EXPECT_EQ(j["name"], "fwhm_800nm");
  EXPECT_NEAR(j["value"].get<double>(), 8.8, 1e-12);
  EXPECT_EQ(j["limit"].get<double>(), 10.8);
  EXPECT_TRUE(j["pass"].get<bool>());
  EXPECT_EQ(j["verdict"], "pass");
  EXPECT_EQ(j["comparison"], "<=");
  EXPECT_TRUE(j["reason"].is_null());
}

TEST(Requirements, OneGroupsDrawsAreJudgedWithoutARelation) {
  // FWHM draws 10.005 .. 10.995 (median 10.5): <= 10.8 for k - 49.5 <= 30, i.e. 80 draws.
  const RequirementResult r =
      EvaluateRequirementOnDraws(DefaultRequirements()[0], Ladder(10.5, 0.01));
  ASSERT_TRUE(r.pass.has_value()) << r.reason;
  EXPECT_TRUE(*r.pass);
  EXPECT_NEAR(r.value.median, 10.5, 1e-12);
  EXPECT_NEAR(r.margin, 0.3, 1e-12);
  EXPECT_NEAR(r.pass_probability, 0.80, 1e-12);
  EXPECT_EQ(Verdict(r), "undetermined");
  // A coefficient needs a relation; no draws is no value.
  const RequirementResult coefficient =
      EvaluateRequirementOnDraws(DefaultRequirements()[2], Ladder(-0.27, 0.001));
  EXPECT_FALSE(coefficient.pass.has_value());
  EXPECT_NE(coefficient.reason.find("coefficient"), std::string::npos) << coefficient.reason;
  const RequirementResult none = EvaluateRequirementOnDraws(DefaultRequirements()[0], {});
  EXPECT_FALSE(none.pass.has_value());
  EXPECT_EQ(none.reason, "no draws of 'fwhm_um'");
}

TEST(Requirements, CombinedModelAwayFromI0UsesTheIntensityRelation) {
  std::map<std::string, RelationFit> relations;
  relations["fwhm_um_vs_wavelength"] =
      HandPowerLaw(std::vector<double>(100, 8.8), std::vector<double>(100, -0.272));
  relations["fwhm_um_vs_intensity"] = HandLinear(6.61, 1.14e-5);
  Requirement r = DefaultRequirements()[0];
  r.wavelength_nm = 700.0;
  r.intensity_e = 5.0e4;
  const RequirementResult res = EvaluateRequirements({r}, relations)[0];
  ASSERT_TRUE(res.pass.has_value()) << res.reason;
  const double expected =
      (6.61 + 1.14e-5 * 5.0e4) / (6.61 + 1.14e-5 * 157800.0) * 8.8 * std::pow(700.0 / 800.0, -0.272);
  EXPECT_NEAR(res.value.median, expected, 1e-12 * expected);
  EXPECT_NEAR(res.margin, 10.8 - expected, 1e-12);
}

TEST(Requirements, MissingInputsGiveNullWithAReason) {
  std::map<std::string, RelationFit> relations;
  RelationFit not_fitted;
  not_fitted.kind = RelationKind::kPowerLaw;
  not_fitted.flags.push_back({kFlagNotFitted, "1 usable point(s): a relation needs at least 2"});
  relations["fwhm_um_vs_wavelength"] = not_fitted;
  const std::vector<RequirementResult> results =
      EvaluateRequirements(DefaultRequirements(), relations);
  for (const RequirementResult& r : results) {
    EXPECT_FALSE(r.pass.has_value()) << r.requirement.name;
    EXPECT_TRUE(std::isnan(r.value.median));
    EXPECT_TRUE(std::isnan(r.margin));
    EXPECT_FALSE(r.reason.empty());
    const nlohmann::json j = ToJson(r);
    EXPECT_TRUE(j["pass"].is_null());
    EXPECT_EQ(j["verdict"], "n/a");
    EXPECT_TRUE(j["value"].is_null());
    EXPECT_TRUE(j["margin"].is_null());
    EXPECT_EQ(j["reason"], r.reason);
  }
  EXPECT_NE(ByName(results, "fwhm_800nm").reason.find("not fitted: 1 usable point"),
            std::string::npos)
      << ByName(results, "fwhm_800nm").reason;
  EXPECT_EQ(ByName(results, "ellipticity_800nm").reason,
            "relation 'ellipticity_vs_wavelength' is absent");
  // Away from I0 the intensity relation is needed too.
  relations["fwhm_um_vs_wavelength"] =
      HandPowerLaw(std::vector<double>(100, 8.8), std::vector<double>(100, -0.272));
  Requirement r = DefaultRequirements()[0];
  r.intensity_e = 5.0e4;
  const RequirementResult res = EvaluateRequirements({r}, relations)[0];
  EXPECT_FALSE(res.pass.has_value());
  EXPECT_NE(res.reason.find("fwhm_um_vs_intensity"), std::string::npos) << res.reason;
  const std::string table = FormatRequirementTable(results);
  EXPECT_NE(table.find("fwhm_800nm"), std::string::npos);
  EXPECT_NE(table.find("n/a (relation 'ellipticity_vs_wavelength' is absent)"), std::string::npos)
      << table;
}

TEST(Requirements, RelationFlagsAreCopiedIntoTheNotes) {
  std::map<std::string, RelationFit> relations;
  relations["fwhm_um_vs_wavelength"] = HandPowerLaw(Ladder(8.8, 0.01), Ladder(-0.27, 0.001));
  relations["fwhm_um_vs_wavelength"].flags.push_back(
      {kFlagPoorlyConstrained, "3 points, 1 degree of freedom: ..."});
  Requirement r = DefaultRequirements()[0];
  r.wavelength_nm = 550.0;  // outside 600-890 nm
  const RequirementResult res = EvaluateRequirements({r}, relations)[0];
  ASSERT_TRUE(res.pass.has_value());
  ASSERT_EQ(res.notes.size(), 2u);
  EXPECT_EQ(res.notes[0],
            "fwhm_um_vs_wavelength: poorly_constrained: 3 points, 1 degree of freedom: ...");
  EXPECT_NE(res.notes[1].find("extrapolated"), std::string::npos);
}

TEST(Requirements, ParsesTheJsonConfiguration) {
  std::string error;
  const auto parsed = ParseRequirementsText(R"([
      {"name": "fwhm_800nm", "metric": "fwhm_um",
       "at": {"wavelength_nm": 800, "intensity_e": 157800}, "max": 10.8},
      {"name": "alpha_fwhm", "relation": "fwhm_um_vs_wavelength", "coefficient": "alpha",
       "max": -0.2},
      {"name": "slope_min", "relation": "fwhm_um_vs_intensity", "coefficient": "slope",
       "min": 0},
      {"name": "e_600", "metric": "ellipticity", "at": {"wavelength_nm": 600}, "max": 0.156}])",
                                            &error);
  ASSERT_TRUE(parsed.has_value()) << error;
  ASSERT_EQ(parsed->size(), 4u);
  const std::vector<Requirement>& r = *parsed;
  EXPECT_EQ(r[0].target, Requirement::Target::kMetricAt);
  EXPECT_EQ(r[0].limit, 10.8);
  EXPECT_EQ(r[0].comparison, Comparison::kAtMost);
  EXPECT_EQ(r[1].target, Requirement::Target::kCoefficient);
  EXPECT_EQ(r[1].coefficient, "alpha");
  EXPECT_EQ(r[2].comparison, Comparison::kAtLeast);
  EXPECT_EQ(r[2].limit, 0.0);
  EXPECT_EQ(r[3].intensity_e, kReferenceIntensityE);  // default I0
  EXPECT_EQ(r[3].wavelength_nm, 600.0);

  // Round trip of the configuration form.
  const auto again = ParseRequirements(RequirementsToJson(r), &error);
  ASSERT_TRUE(again.has_value()) << error;
  EXPECT_EQ(RequirementsToJson(*again), RequirementsToJson(r));
  const auto defaults = ParseRequirements(RequirementsToJson(DefaultRequirements()), &error);
  ASSERT_TRUE(defaults.has_value()) << error;
  EXPECT_EQ(RequirementsToJson(*defaults), RequirementsToJson(DefaultRequirements()));
}

TEST(Requirements, JsonErrorsAreOneLineAndNameTheEntry) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {R"({"name": "x"})", "must be a JSON list"},
      {R"([3])", "requirements[0]: must be a JSON object"},
      {R"([{"name": "x", "metric": "fwhm_um", "at": {"wavelength_nm": 800}, "maxx": 1}])",
       "requirements[0]: give exactly one of 'max'"},
      {R"([{"name": "x", "metric": "fwhm_um", "at": {"wavelength_nm": 800}, "max": 1,
            "colour": "red"}])",
       "unknown key 'requirements[0].colour'"},
      {R"([{"name": "x", "metric": "fwhm_um", "at": {"wavelength_nm": 800}, "max": 1,
            "min": 0}])",
       "give exactly one of 'max'"},
      {R"([{"name": "x", "metric": "fwhm_um", "max": 1}])", "'requirements[0].at' is required"},
      {R"([{"name": "x", "metric": "fwhm_um", "at": {"wavelength": 800}, "max": 1}])",
       "'requirements[0].at.wavelength_nm' is required"},
      {R"([{"name": "x", "metric": "fwhm_um", "at": {"wavelength_nm": 800, "i": 1}, "max": 1}])",
       "unknown key 'requirements[0].at.i'"},
      {R"([{"name": "x", "metric": "fwhm_mu", "at": {"wavelength_nm": 800}, "max": 1}])",
       "unknown metric 'fwhm_mu'"},
      {R"([{"name": "x", "relation": "fwhm_um_vs_wavelength", "coefficient": "slope",
            "max": 1}])",
       "has no coefficient 'slope'"},
      {R"([{"name": "x", "relation": "fwhm_um_vs_colour", "coefficient": "a", "max": 1}])",
       "unknown relation 'fwhm_um_vs_colour'"},
      {R"([{"name": "x", "metric": "fwhm_um", "relation": "fwhm_um_vs_wavelength",
            "max": 1}])",
       "give either 'metric'"},
      {R"([{"name": "x", "relation": "fwhm_um_vs_wavelength", "max": 1}])",
       "'requirements[0].coefficient' is required"},
      {R"([{"name": "x", "metric": "fwhm_um", "at": {"wavelength_nm": 800}, "max": "10.8"}])",
       "'requirements[0].max' must be a finite number"},
      {R"([{"metric": "fwhm_um", "at": {"wavelength_nm": 800}, "max": 1}])",
       "'requirements[0].name' is required"},
      {R"([{"name": "x", "metric": "fwhm_um", "at": {"wavelength_nm": -5}, "max": 1}])",
       "wavelength_nm must be a finite number > 0"},
      {R"([{"name": "x", "relation": "fwhm_um_vs_wavelength", "coefficient": "a", "max": 1},
           {"name": "x", "relation": "fwhm_um_vs_wavelength", "coefficient": "alpha",
            "max": 1}])",
       "requirements[1]: duplicate requirement name 'x'"},
      {R"([{"name": "x", )", "not valid JSON"},
  };
  for (const auto& [text, expected] : cases) {
    std::string error;
    EXPECT_FALSE(ParseRequirementsText(text, &error).has_value()) << text;
    EXPECT_NE(error.find(expected), std::string::npos) << text << "\n  -> " << error;
    EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  }
}

}  // namespace
}  // namespace ccdpsf::trend
