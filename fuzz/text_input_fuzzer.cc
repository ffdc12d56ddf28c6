// libFuzzer harness for the text inputs: whatever bytes arrive as FIT.json, a manifest (CSV
// or JSON), a simulation or campaign config, a requirements list, a keyword map, an effect
// list, an IRAF section, a truth file, a stored group result or a ptc.json taken as a prior
// (--ptc) must be parsed into a value
// or refused with a one-line error, never crash, hang or allocate without bound. The first
// byte chooses the reader; the rest is the text. Built with -DCCDPSF_FUZZ=ON (clang); see
// the README's "Fuzzing" section for the runs, fuzz/text_corpus/ for the seeds and
// fuzz/text.dict for the tokens.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/campaign_simulation.h"
#include "ccdpsf/exposure.h"
#include "ccdpsf/fit/fit_config.h"
#include "ccdpsf/input_file.h"
#include "ccdpsf/manifest.h"
#include "ccdpsf/metadata.h"
#include "ccdpsf/ptc_prior.h"
#include "ccdpsf/simulate.h"
#include "ccdpsf/trend/group_store.h"
#include "ccdpsf/trend/requirements.h"
#include "ccdpsf/truth.h"
#include "nlohmann/json.hpp"

namespace {

// A private folder for the inputs that are read from files (manifests, truth, keyword
// maps): one per process (libFuzzer's workers are processes), under TMPDIR.
std::string g_dir;

// Writes `text` to g_dir/name and returns the path.
std::string WriteInput(const std::string& name, const std::string& text) {
  const std::string path = g_dir + "/" + name;
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) std::abort();
  if (!text.empty() && std::fwrite(text.data(), 1, text.size(), file) != text.size()) {
    std::abort();
  }
  std::fclose(file);
  return path;
}

// The readers, one per value of the first byte (modulo their number).
enum Reader : uint8_t {
  kFitConfig,
  kManifestCsv,
  kManifestJson,
  kSimulationConfig,
  kCampaignConfig,
  kRequirements,
  kKeywordMapText,
  kKeywordMapFile,
  kEffectList,
  kSection,
  kTruth,
  kGroupResult,
  kPtcPrior,
  kNumReaders
};

void Parse(Reader reader, const std::string& text) {
  std::string error;
  switch (reader) {
    case kFitConfig: {
      ccdpsf::fit::FitConfig config;
      if (ccdpsf::fit::ParseFitConfig(text, &config, &error)) {
        (void)config.calibration.IsValid(&error);
        (void)ccdpsf::fit::FitConfigJson(config).dump();
      }
      break;
    }
    case kManifestCsv:
    case kManifestJson: {
      const std::string path =
          WriteInput(reader == kManifestCsv ? "manifest.csv" : "manifest.json", text);
      ccdpsf::Manifest manifest;
      if (ccdpsf::LoadManifest(path, &manifest, &error)) {
        for (const ccdpsf::ManifestRow& row : manifest.rows) (void)manifest.Find(row.file);
      }
      break;
    }
    case kSimulationConfig:
      (void)ccdpsf::ParseSimulationConfig(text, &error);
      break;
    case kCampaignConfig:
      (void)ccdpsf::ParseCampaignConfig(text, &error);
      break;
    case kRequirements:
      (void)ccdpsf::trend::ParseRequirementsText(text, &error);
      break;
    case kKeywordMapText: {
      ccdpsf::KeywordMap map;
      (void)map.OverlayText(text, &error);
      break;
    }
    case kKeywordMapFile: {
      ccdpsf::KeywordMap map;
      (void)map.OverlayFileOrText(WriteInput("keywords.json", text), &error);
      break;
    }
    case kEffectList: {
      std::vector<ccdpsf::fit::FitEffect> effects;
      (void)ccdpsf::fit::ParseFitEffectList(text, &effects, &error);
      break;
    }
    case kSection:
      (void)ccdpsf::ParseIrafSection(text, 4096, 4096, &error);
      break;
    case kTruth: {
      std::optional<ccdpsf::TruthFile> truth;
      (void)ccdpsf::FindTruth(WriteInput("truth.json", text), {}, &truth, &error);
      break;
    }
    case kGroupResult: {
      ccdpsf::trend::GroupResult result;
      const nlohmann::json j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
      // The caller knows its group's name; the harness takes it from the text where it is a
      // string (json::value() would throw on another type, in the harness, not the reader).
      if (j.is_object() && j.contains("group") && j["group"].is_string()) {
        result.group.name = j["group"].get<std::string>();
      }
      (void)ccdpsf::trend::GroupResultFromJson(j, &result);
      break;
    }
    case kPtcPrior: {
      ccdpsf::fit::GaussianPrior prior;
      (void)ccdpsf::ParsePtcPrior(text, "ptc.json", &prior, &error);
      break;
    }
    case kNumReaders:
      break;
  }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  const char* tmp = std::getenv("TMPDIR");
  const std::string pattern = std::string(tmp != nullptr ? tmp : "/tmp") + "/ccdpsf_text_XXXXXX";
  std::vector<char> buffer(pattern.begin(), pattern.end());
  buffer.push_back('\0');
  if (::mkdtemp(buffer.data()) == nullptr) {
    std::perror("mkdtemp");
    std::abort();
  }
  g_dir = buffer.data();
  // Removed at a normal exit; after a crash libFuzzer keeps the input as crash-<sha1>.
  std::atexit([] {
    for (const char* name : {"manifest.csv", "manifest.json", "keywords.json", "truth.json"}) {
      ::unlink((g_dir + "/" + name).c_str());
    }
    ::rmdir(g_dir.c_str());
  });
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // The tool reads no text input above this ceiling (input_file.h); the readers see none.
  if (size == 0 || static_cast<long long>(size) > ccdpsf::kMaxTextInputBytes) return 0;
  const Reader reader = static_cast<Reader>(data[0] % kNumReaders);
  Parse(reader, std::string(reinterpret_cast<const char*>(data) + 1, size - 1));
  return 0;
}
