// Reading the tool's inputs safely: only regular files, and text only up to a ceiling.
//
// A FIFO, a terminal, /dev/zero or a folder given where a file is expected is refused by
// its type at once (it could block forever or never end), and every text input (FIT.json,
// manifests, truth.json, requirements, keyword maps, simulation and campaign configs) is
// read whole only below kMaxTextInputBytes, so that no input can make the tool hang or grow
// without bound (README, "Bounded inputs").
#ifndef CCDPSF_INPUT_FILE_H_
#define CCDPSF_INPUT_FILE_H_

#include <string>

namespace ccdpsf {

// The largest text input read [bytes]: 16 MiB, some thousand times a large manifest.
constexpr long long kMaxTextInputBytes = 16LL << 20;

// Opens `path` for reading if it is a regular file (a symbolic link to one is followed) and
// returns the descriptor (the caller closes it). Otherwise -1, with a one-line reason that
// names `what` ("manifest", "fit config"; empty: the path alone): "cannot read manifest 'x':
// no such file", "manifest 'x' is a FIFO, not a regular file", ... The open never blocks,
// whatever the file is.
int OpenRegularFile(const std::string& path, const std::string& what, std::string* error);

// Reads the whole text input `path` into *text: a regular file of at most `max_bytes`.
// False with a one-line reason naming `what`.
bool ReadTextInput(const std::string& path, const std::string& what, std::string* text,
                   std::string* error, long long max_bytes = kMaxTextInputBytes);

}  // namespace ccdpsf

#endif  // CCDPSF_INPUT_FILE_H_
