// Screening untrusted FITS files before CFITSIO parses them (fits_io.cc reads through it).
//
// CFITSIO trusts a file's header. A tile-compressed image with ZTILE1 = 0 divides by zero
// as soon as CFITSIO moves to its HDU (fits_get_num_hdus does, for every HDU): SIGFPE, no
// message. A corrupt RICE_1 stream makes its decoder read past the tile's buffer. A header
// claiming 16000 x 16000 pixels makes the caller allocate 2 GB of doubles. So before CFITSIO
// opens a file the reader walks every HDU's header itself (FITS standard 4.0, sections 4 and
// 7; tiled images: section 10) and refuses what CFITSIO could not survive or what exceeds the
// memory ceiling; before it reads a tile-compressed image it checks where each tile lies and
// walks each RICE_1 stream the way CFITSIO's decoder will, with bounds.
//
// The screen is stricter than CFITSIO wherever the two could read a header differently: a
// keyword that matters must be a plain integer (CFITSIO would also take "64.7" or T), may
// not appear twice with different values, and the mandatory ones must stand where the
// standard puts them (CFITSIO reads those by position); the END card is recognised as
// CFITSIO recognises it. A header the screen cannot parse is refused, so that CFITSIO never
// reaches an HDU the screen has not seen. Where the file ends inside a header the screen
// checks the mandatory keywords there and stops: CFITSIO cannot go further either, and
// reports the truncation.
#ifndef CCDPSF_INTERNAL_FITS_SCREEN_H_
#define CCDPSF_INTERNAL_FITS_SCREEN_H_

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <sys/types.h>
#include <vector>

namespace ccdpsf::internal {

// The bytes of a file being read: on disk (read at offsets), or in memory (a decompressed
// gzip file, which CFITSIO then reads from there too).
class FileBytes {
 public:
  FileBytes() = default;
  ~FileBytes() {
    if (stream_ != nullptr) std::fclose(stream_);
    std::free(memory_);
  }
  FileBytes(const FileBytes&) = delete;
  FileBytes& operator=(const FileBytes&) = delete;

  bool OpenDisk(const std::string& path) {
    stream_ = std::fopen(path.c_str(), "rb");
    if (stream_ == nullptr || fseeko(stream_, 0, SEEK_END) != 0) return false;
    size_ = ftello(stream_);
    return size_ >= 0;
  }
  // Back to nothing read (closing the file, freeing the memory).
  void Reset() {
    if (stream_ != nullptr) std::fclose(stream_);
    std::free(memory_);
    stream_ = nullptr;
    memory_ = nullptr;
    memory_size_ = 0;
    size_ = 0;
  }
  // Takes a malloc'ed block whose first `size` bytes are the file.
  void TakeMemory(char* memory, size_t size) {
    memory_ = memory;
    memory_size_ = size;
    size_ = static_cast<long long>(size);
  }
  bool in_memory() const { return memory_ != nullptr; }
  long long size() const { return size_; }
  // For fits_open_memfile, which keeps these addresses for as long as the file is open.
  void** memory_slot() { return &memory_; }
  size_t* memory_size_slot() { return &memory_size_; }

  // Copies n bytes at `offset` to `out`; false if any of them lies beyond the end.
  bool Read(long long offset, size_t n, void* out) const {
    if (offset < 0 || static_cast<unsigned long long>(n) > static_cast<unsigned long long>(size_) ||
        offset > size_ - static_cast<long long>(n)) {
      return false;
    }
    if (n == 0) return true;
    if (memory_ != nullptr) {
      std::memcpy(out, static_cast<const char*>(memory_) + offset, n);
      return true;
    }
    return fseeko(stream_, offset, SEEK_SET) == 0 && std::fread(out, 1, n, stream_) == n;
  }

 private:
  std::FILE* stream_ = nullptr;
  void* memory_ = nullptr;
  size_t memory_size_ = 0;
  long long size_ = 0;
};

// One column of a binary table: its TFORMn read as repeat, type and (for P and Q
// descriptors) the type of the array's elements; its byte offset within a row.
struct TableColumn {
  std::string name;     // TTYPEn, upper case
  std::string form;     // TFORMn as written
  long long repeat = 1;
  char type = 0;        // L X B I J K A E D C M P Q
  char element = 0;     // for P and Q: the element type
  long long offset = 0;
  long long width = 0;  // bytes in a row
};

// A tile-compressed image (a BINTABLE with ZIMAGE = T), as the screen read it.
struct TiledImage {
  std::string compression;           // ZCMPTYPE, upper case; RICE_ONE is read as RICE_1
  std::vector<long long> axes;       // ZNAXISn
  std::vector<long long> tile;       // ZTILEn (defaults applied)
  int rice_block = 0;                // RICE_1 pixels per block and bytes per pixel, as
  int rice_bytepix = 0;              // CFITSIO takes them from ZVAL1 / ZVAL2
  std::string column_problem;        // why the table's columns cannot be read, if they cannot
  int data_column = -1;              // COMPRESSED_DATA, GZIP_COMPRESSED_DATA and
  int gzip_column = -1;              // UNCOMPRESSED_DATA in `columns` (-1: none)
  int raw_column = -1;
};

// One HDU as the screen walked it.
struct HduLayout {
  int number = 0;                 // 1-based, as CFITSIO counts
  long long data_start = 0;       // byte offset of the data unit
  long long data_bytes = 0;       // its size without the padding to a block
  bool table = false;             // a binary or ASCII table (not an image)
  std::vector<long long> naxes;
  long long pcount = 0;
  long long heap_offset = 0;      // THEAP: the heap's start within the data unit
  std::vector<TableColumn> columns;
  bool tiled = false;
  TiledImage image;
};

// "1.9 GB", "64.0 MB", "300 bytes" in binary units (1 MB = 2^20 bytes), as --max_image_mb.
std::string FormatBytes(double bytes);

// Where a problem is, in messages: "'f.fits'" for the primary HDU, "'f.fits' HDU 2" for
// extension 2 (numbered as ReadFitsImage's selector, 0 = primary). `hdu` is 1-based.
std::string HduWhere(const std::string& path, int hdu);

// The memory-ceiling check for an image of the given axes, read as doubles. Empty if it fits.
std::string CheckImageSize(const std::string& where, const std::vector<long long>& axes);

// Decompresses the gzip file at `path` into memory, at most `limit` bytes. *complete is
// false when the output reached the limit (the bytes so far are kept: their headers can
// still be screened). The size the gzip trailer claims is not used: it can lie. False with
// a one-line reason when the stream is corrupt or memory runs out.
bool Gunzip(const std::string& path, size_t limit, FileBytes* bytes, bool* complete,
            std::string* error);

// Walks every HDU of `bytes` as CFITSIO will (see above). False with a one-line reason if
// the file must not reach CFITSIO; *hdus receives the HDUs whose headers are complete.
bool ScreenFile(const FileBytes& bytes, const std::string& path, std::vector<HduLayout>* hdus,
                std::string* error);

// Checks every tile of the tile-compressed image `hdu` before CFITSIO decompresses it:
// each descriptor must point inside the heap; a RICE_1 stream must stay inside its bytes;
// a GZIP stream must inflate to at most the tile's pixels at 8 bytes each. Compression
// types whose decoders cannot be checked so (HCOMPRESS_1, PLIO_1, BZIP2_1, NOCOMPRESS) are
// refused. False with a one-line reason.
bool CheckTiles(const FileBytes& bytes, const HduLayout& hdu, const std::string& where,
                std::string* error);

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_FITS_SCREEN_H_
