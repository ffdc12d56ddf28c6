// Multi-file results that appear all at once or not at all.
//
// Files are written into a private staging folder inside the output folder; Commit() moves
// them into place in the order given, so the file named last (e.g. fit.json) appearing
// means every other one is complete. If Commit() is never reached, the destructor removes
// the staging folder and nothing of the failed run is left.
#ifndef CCDPSF_STAGED_OUTPUT_H_
#define CCDPSF_STAGED_OUTPUT_H_

#include <string>
#include <vector>

namespace ccdpsf {

class StagedOutput {
 public:
  StagedOutput() = default;
  ~StagedOutput();
  StagedOutput(const StagedOutput&) = delete;
  StagedOutput& operator=(const StagedOutput&) = delete;

  // Creates out_dir (and parents) and the staging folder. False with a reason on failure.
  bool Begin(const std::string& out_dir, std::string* error);

  // Where to write file `name` (a plain file name) before Commit().
  std::string Path(const std::string& name) const { return staging_ + "/" + name; }
  const std::string& staging_dir() const { return staging_; }

  // Moves every file of the staging folder into out_dir: first those not listed in `last`,
  // then those in `last`, in that order. A stale copy of each `last` file is removed before
  // anything moves, so it never describes new results. Then removes the staging folder.
  bool Commit(const std::vector<std::string>& last, std::string* error);

 private:
  std::string out_dir_;
  std::string staging_;
};

}  // namespace ccdpsf

#endif  // CCDPSF_STAGED_OUTPUT_H_
