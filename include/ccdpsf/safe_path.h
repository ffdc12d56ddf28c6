// The one rule for paths the tool writes or removes (README, "The output folder"): every such
// path lies inside the run's output folder and is built from safe components. A name that
// comes from an input (a file's stem, a manifest's setting, a group name) is never joined to
// a path as it is: SafeComponent turns it into one component that cannot climb out ("..")
// or hide (a leading '.'), and IsInsideFolder checks a finished path before it is removed.
#ifndef CCDPSF_SAFE_PATH_H_
#define CCDPSF_SAFE_PATH_H_

#include <string>
#include <vector>

namespace ccdpsf {

// `name` as a single path component: letters, digits and - _ . + = , @ kept, every other
// byte (a '/', a control character, a space) replaced by '_'; a name that is empty, starts
// with '.' (".", "..", a hidden name) or is longer than 120 bytes is prefixed by '_' or
// shortened, so that the result never names a parent, the folder itself or a hidden file.
std::string SafeComponent(const std::string& name);

// SafeComponent of each name, made unique: the second of two equal results gets "_2", the
// third "_3", and so on (the order of `names` decides, so equal inputs give equal folders).
// Compared without case, so that case-insensitive file systems do not merge two of them.
std::vector<std::string> UniqueSafeComponents(const std::vector<std::string>& names);

// True if `path` lies strictly inside `folder`: lexically below it, with no ".." component
// and no symbolic link on the way from `folder` down to `path`'s parent (the last component
// may be a link: removing a link removes the link, not its target). False with a one-line
// reason. `folder` itself is trusted (the run created or checked it).
bool IsInsideFolder(const std::string& folder, const std::string& path, std::string* error);

}  // namespace ccdpsf

#endif  // CCDPSF_SAFE_PATH_H_
