// The FITS input stage on a file of N tiny image extensions without --hdu (issue 42): every
// extension is screened and tried for a spot. The reader opened and screened the file once
// per extension (O(N^2): 1000 HDUs 8 s, 2000 HDUs 40 s); now it opens it once, so the time
// per HDU should not grow with N.
// Run: ./build/fits_hdus_benchmark --benchmark_repetitions=3 --benchmark_report_aggregates_only=true
#include <algorithm>
#include <cstdio>
#include <string>

#include "benchmark/benchmark.h"
#include "ccdpsf/exposure.h"

namespace {

// One 80-character header card and a header padded to whole 2880-byte blocks.
std::string Card(const std::string& key, const std::string& value) {
  std::string card = key;
  card.resize(8, ' ');
  card += "= " + std::string(20 - std::min<size_t>(20, value.size()), ' ') + value;
  card.resize(80, ' ');
  return card;
}
std::string Header(std::initializer_list<std::string> cards) {
  std::string h;
  for (const std::string& c : cards) h += c;
  h += std::string("END").append(77, ' ');
  h.resize((h.size() + 2879) / 2880 * 2880, ' ');
  return h;
}

// An empty primary HDU and n extensions of 4 x 4 zeros, written to a scratch file.
std::string WriteManyHdus(int n) {
  std::string bytes = Header({Card("SIMPLE", "T"), Card("BITPIX", "16"), Card("NAXIS", "0"),
                              Card("EXTEND", "T")});
  const std::string data(2880, '\0');
  for (int k = 0; k < n; ++k) {
    bytes += Header({Card("XTENSION", "'IMAGE   '"), Card("BITPIX", "16"), Card("NAXIS", "2"),
                     Card("NAXIS1", "4"), Card("NAXIS2", "4"), Card("PCOUNT", "0"),
                     Card("GCOUNT", "1")});
    bytes += data;
  }
  const std::string path = "/tmp/ccdpsf_fits_hdus_benchmark_" + std::to_string(n) + ".fits";
  std::FILE* f = std::fopen(path.c_str(), "wb");
  std::fwrite(bytes.data(), 1, bytes.size(), f);
  std::fclose(f);
  return path;
}

void BM_LoadManyHdus(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const std::string path = WriteManyHdus(n);
  ccdpsf::CalibrationOptions options;
  options.Set("gain_e_per_adu", 2.0);
  options.Set("pixel_um", 12.0);
  for (auto _ : state) {
    std::string error;
    // No spot in any segment: the load ends with a one-line reason after trying them all.
    if (ccdpsf::LoadExposure(path, options, &error).has_value()) {
      state.SkipWithError("a spot was found where there is none");
    }
  }
  state.counters["s_per_hdu"] = benchmark::Counter(
      n, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
  std::remove(path.c_str());
}
BENCHMARK(BM_LoadManyHdus)->Arg(250)->Arg(1000)->Arg(2000)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
