#include "ccdpsf/fit/sampler_checkpoint.h"

#include <cstring>
#include <fstream>
#include <limits>
#include <type_traits>

#include "ccdpsf/atomic_file.h"
#include "internal/fnv1a.h"

namespace ccdpsf::fit {
namespace {

constexpr char kMagic[8] = {'C', 'C', 'D', 'P', 'S', 'F', 'M', 'C'};
// 2: the independence move's per-walker counts after `accepted`.
// 3: a checksum of everything before it at the end of the file.
constexpr uint32_t kVersion = 3;

// The checksum at the end of a checkpoint, over every byte before it (damage, not forgery).
uint64_t Checksum(const char* data, size_t size) {
  internal::Fnv1a h;
  h.Add(data, size);
  return h.value();
}

class Writer {
 public:
  explicit Writer(std::string* out) : out_(out) {}
  template <typename T>
  void Value(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    out_->append(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  template <typename T>
  void Vector(const std::vector<T>& v) {
    Value<uint64_t>(v.size());
    if (!v.empty()) out_->append(reinterpret_cast<const char*>(v.data()), sizeof(T) * v.size());
  }
  void Text(const std::string& s) {
    Value<uint64_t>(s.size());
    out_->append(s);
  }

 private:
  std::string* out_;
};

class Reader {
 public:
  Reader(const char* data, uint64_t size) : data_(data), left_(size) {}
  template <typename T>
  bool Value(T* v) {
    return Bytes(reinterpret_cast<char*>(v), sizeof(T));
  }
  template <typename T>
  bool Vector(std::vector<T>* v) {
    uint64_t n = 0;
    // The count must fit in what is left of the file: a corrupt count allocates nothing.
    if (!Value(&n) || n > left_ / sizeof(T)) return false;
    v->resize(n);
    return n == 0 || Bytes(reinterpret_cast<char*>(v->data()), sizeof(T) * n);
  }
  bool Text(std::string* s) {
    uint64_t n = 0;
    if (!Value(&n) || n > left_) return false;
    s->resize(n);
    return n == 0 || Bytes(s->data(), n);
  }
  bool AtEnd() const { return left_ == 0; }

 private:
  bool Bytes(char* to, uint64_t n) {
    if (n > left_) return false;
    std::memcpy(to, data_, n);
    data_ += n;
    left_ -= n;
    return true;
  }
  const char* data_;
  uint64_t left_;
};

}  // namespace

bool WriteSamplerCheckpoint(const std::string& path, const SamplerCheckpoint& c,
                            std::string* error) {
  std::string bytes(kMagic, sizeof(kMagic));
  Writer w(&bytes);
  w.Value(kVersion);
  w.Value(c.fingerprint);
  w.Value(c.steps);
  w.Value(c.next_check);
  w.Value(c.previous_max_tau);
  w.Vector(c.positions);
  w.Vector(c.log_prob);
  w.Vector(c.accepted);
  w.Vector(c.independence_proposed);
  w.Vector(c.independence_accepted);
  w.Vector(c.conditional_acceptance);
  w.Vector(c.aux);
  w.Value<uint64_t>(c.engines.size());
  for (const std::string& e : c.engines) w.Text(e);
  w.Vector(c.chain);
  w.Vector(c.chain_log_prob);
  w.Value(Checksum(bytes.data(), bytes.size()));
  return WriteAtomically(
      path,
      [&bytes](const std::string& temp, std::string* err) {
        std::ofstream out(temp, std::ios::binary);
        out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
        out.close();
        if (!out) {
          *err = "cannot write the MCMC checkpoint '" + temp + "'";
          return false;
        }
        return true;
      },
      error);
}

bool ReadSamplerCheckpoint(const std::string& path, SamplerCheckpoint* c, std::string* error) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) {
    *error = "no MCMC checkpoint at '" + path + "'";
    return false;
  }
  const auto size = static_cast<uint64_t>(in.tellg());
  in.seekg(0);
  std::string bytes(size, '\0');
  if (!in.read(bytes.data(), static_cast<std::streamsize>(size))) {
    *error = "cannot read the MCMC checkpoint '" + path + "'";
    return false;
  }
  uint64_t stored = 0;
  const size_t body = size >= sizeof(stored) ? size - sizeof(stored) : 0;
  if (size >= sizeof(stored)) std::memcpy(&stored, bytes.data() + body, sizeof(stored));
  if (size < sizeof(kMagic) + sizeof(stored) || Checksum(bytes.data(), body) != stored) {
    *error = "'" + path + "' is damaged (its checksum does not match its contents)";
    return false;
  }
  Reader r(bytes.data(), body);
  char magic[sizeof(kMagic)] = {};
  uint32_t version = 0;
  uint64_t engines = 0;
  SamplerCheckpoint read;
  bool ok = r.Value(&magic) && std::memcmp(magic, kMagic, sizeof(kMagic)) == 0 &&
            r.Value(&version) && version == kVersion && r.Value(&read.fingerprint) &&
            r.Value(&read.steps) && r.Value(&read.next_check) && r.Value(&read.previous_max_tau) &&
            r.Vector(&read.positions) && r.Vector(&read.log_prob) && r.Vector(&read.accepted) &&
            r.Vector(&read.independence_proposed) && r.Vector(&read.independence_accepted) &&
            r.Vector(&read.conditional_acceptance) && r.Vector(&read.aux) && r.Value(&engines) &&
            engines <= size;
  for (uint64_t i = 0; ok && i < engines; ++i) {
    read.engines.emplace_back();
    ok = r.Text(&read.engines.back());
  }
  ok = ok && r.Vector(&read.chain) && r.Vector(&read.chain_log_prob) && r.AtEnd();
  if (!ok) {
    *error = "'" + path + "' is not a complete MCMC checkpoint of this version";
    return false;
  }
  *c = std::move(read);
  return true;
}

}  // namespace ccdpsf::fit
