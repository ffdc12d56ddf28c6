// Writing result files so that a failure never leaves a complete-looking partial file.
#ifndef CCDPSF_ATOMIC_FILE_H_
#define CCDPSF_ATOMIC_FILE_H_

#include <functional>
#include <string>

namespace ccdpsf {

// Creates `dir` and its parents if needed. Returns false with a one-line reason if it cannot
// (a file is in the way, permissions, ...).
bool MakeDirectories(const std::string& dir, std::string* error);

// Calls write(temp_path, error) to produce the file at a temporary path in the same folder as
// `path`, then renames it onto `path` (atomic on POSIX). If write returns false, or the rename
// fails, the temporary file is removed and false is returned with the reason in *error.
bool WriteAtomically(const std::string& path,
                     const std::function<bool(const std::string& temp_path, std::string* error)>& write,
                     std::string* error);

// Writes `contents` to `path` atomically (text outputs: JSON, CSV, scripts).
bool WriteTextFileAtomically(const std::string& path, const std::string& contents,
                             std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_ATOMIC_FILE_H_
