// libFuzzer harness for the input stage: whatever bytes arrive as a FITS file (plain or
// gzip), ReadFitsImage, ListFitsImageHdus and the read of every listed HDU must return an
// image or a one-line error, never crash, hang or allocate without bound; and an image that
// was read must survive CalibrateExposure (a fixed gain and pixel size, so that calibration
// runs rather than stopping at "no gain"). Built with -DCCDPSF_FUZZ=ON (clang); see the
// README's "Fuzzing" section for the runs and fuzz/make_corpus.py for the seed corpus.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <string>
#include <vector>

#include "ccdpsf/exposure.h"
#include "ccdpsf/fits_io.h"

namespace {

// The file every input is written to: one per process (libFuzzer's workers are processes),
// under TMPDIR.
std::string g_path;

// Images the harness accepts: 64 MB as doubles (a 2896 x 2896 frame) keeps every input
// fast and far below libFuzzer's 2 GB RSS limit, while the ceiling's check runs on every
// header claiming more.
constexpr long long kFuzzMaxImageBytes = 64LL << 20;

// Calibration of a frame that was read. Errors are expected; only crashes count.
void Calibrate(const ccdpsf::FitsImage& image) {
  ccdpsf::CalibrationOptions options;
  options.Set("gain_e_per_adu", 2.0);
  options.Set("pixel_um", 12.0);
  options.stamp_size = 9;  // small stamps: the corpus's frames are small
  std::string error;
  (void)ccdpsf::CalibrateExposure(image, g_path, options, &error);
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  const char* tmp = std::getenv("TMPDIR");
  const std::string pattern = std::string(tmp != nullptr ? tmp : "/tmp") + "/ccdpsf_fuzz_XXXXXX";
  std::vector<char> buffer(pattern.begin(), pattern.end());
  buffer.push_back('\0');
  const int fd = ::mkstemp(buffer.data());
  if (fd < 0) {
    std::perror("mkstemp");
    std::abort();
  }
  ::close(fd);
  g_path = buffer.data();
  // Removed at a normal exit; after a crash libFuzzer keeps the input as crash-<sha1>.
  std::atexit([] { ::unlink(g_path.c_str()); });
  ccdpsf::SetMaxImageBytes(kFuzzMaxImageBytes);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::FILE* file = std::fopen(g_path.c_str(), "wb");
  if (file == nullptr) std::abort();
  if (size > 0 && std::fwrite(data, 1, size, file) != size) std::abort();
  std::fclose(file);

  std::string error;
  if (const std::optional<ccdpsf::FitsImage> image = ccdpsf::ReadFitsImage(g_path, &error)) {
    Calibrate(*image);
  }
  // A multi-extension file: every image HDU by number, as LoadExposure reads segments, and
  // by name.
  for (const ccdpsf::FitsHduInfo& info : ccdpsf::ListFitsImageHdus(g_path, &error)) {
    if (const std::optional<ccdpsf::FitsImage> image =
            ccdpsf::ReadFitsImage(g_path, std::to_string(info.index), &error)) {
      Calibrate(*image);
    }
    if (!info.extname.empty()) (void)ccdpsf::ReadFitsImage(g_path, info.extname, &error);
  }
  return 0;
}
