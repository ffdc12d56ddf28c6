// `ccdpsf effects`: the catalogue of physical effects (model/effects.h) that the simulator
// injects, diagnose names and fit / trend fit (--effects, FIT.json "effects"), with each
// parameter's unit, realistic default, prior range and physical domain.
#include <cstdio>

#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/model/effects.h"
#include "command.h"
#include "gflags/gflags.h"

DEFINE_bool(json, false, "");

namespace ccdpsf::tools {
namespace {

int RunEffects(const std::vector<std::string>& args) {
  if (!args.empty()) {
    std::fprintf(stderr, "ccdpsf effects: takes no files (got '%s')\n", args[0].c_str());
    return 2;
  }
  if (FLAGS_json) {
    nlohmann::json catalogue = model::EffectCatalogueJson();
    for (nlohmann::json& e : catalogue) {
      model::EffectKind kind;
      std::string why;
      model::ParseEffectKind(e["name"].get<std::string>(), &kind);
      e["fittable"] = fit::IsFittableEffect(kind, &why);
      if (!why.empty()) e["not_fittable_because"] = why;
    }
    std::printf("%s\n", catalogue.dump(2).c_str());
    return 0;
  }
  std::printf("%s", model::FormatEffectCatalogue().c_str());
  std::printf("\nFitted with the spot (fit / trend --effects=a,b or FIT.json \"effects\"): %s",
              fit::FittableEffectNames(" ").c_str());
  std::printf(
      "\n(jitter per exposure in a joint fit, its Gaussian part: the excess variance over the "
      "sharpest exposure; defocus_offset in pixel_centre sampling only, in integrated sampling "
      "it is a shift of the position)\n");
  return 0;
}

}  // namespace

Command EffectsCommand() {
  return {"effects",
          "ccdpsf effects [--json]",
          "List the catalogue of physical effects: parameters, units, defaults, priors.",
          {{"json", "false", "Print the catalogue as JSON"}},
          RunEffects};
}

}  // namespace ccdpsf::tools
