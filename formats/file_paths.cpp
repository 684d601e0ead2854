// Whole files read, and output paths checked against a command's inputs and other
// outputs (file_paths.hpp).
#include "formats/file_paths.hpp"

#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <unistd.h>

namespace mocapd {
namespace {

// Only files: two outputs to /dev/null (or a terminal) are a way to discard them.
bool SameFile(const std::string& a, const std::string& b) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const auto device = [&ec](const std::string& p) {
    return fs::exists(p, ec) && !fs::is_regular_file(p, ec) && !fs::is_directory(p, ec);
  };
  if (device(a) || device(b)) return false;
  // Both exist: the file system says (a hard link has another name, the same file).
  if (fs::exists(a, ec) && fs::exists(b, ec)) {
    const bool same = fs::equivalent(a, b, ec);
    if (!ec) return same;
  }
  const fs::path ca = fs::weakly_canonical(fs::absolute(a), ec);
  if (ec) return false;
  const fs::path cb = fs::weakly_canonical(fs::absolute(b), ec);
  return !ec && ca == cb;
}

// An existing file (or device: /dev/null) must be writable itself; a new one needs its
// folder to exist and take it.
void CheckWritable(const NamedPath& out) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::is_directory(out.path, ec))
    throw std::runtime_error(out.option + " " + out.path + ": is a folder, not a file");
  if (fs::exists(out.path, ec)) {
    if (access(out.path.c_str(), W_OK) != 0)
      throw std::runtime_error(out.option + " " + out.path + ": cannot be written (read-only)");
    return;
  }
  const fs::path parent = fs::absolute(out.path, ec).parent_path();
  if (!fs::is_directory(parent, ec))
    throw std::runtime_error(out.option + " " + out.path + ": the folder " + parent.string() +
                             " does not exist");
  if (access(parent.c_str(), W_OK) != 0)
    throw std::runtime_error(out.option + " " + out.path + ": cannot write in " + parent.string());
}

}  // namespace

std::string ReadWholeFile(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec))
    throw std::runtime_error(path + ": is a folder, not a file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open for reading");
  std::ostringstream bytes;
  // An empty file leaves failbit set here; only badbit is a read that failed.
  if (!(bytes << in.rdbuf()) && in.bad()) throw std::runtime_error(path + ": read failed");
  return std::move(bytes).str();
}

void CheckOutputPaths(std::span<const NamedPath> inputs, std::span<const NamedPath> outputs) {
  for (size_t o = 0; o < outputs.size(); ++o) {
    const NamedPath& out = outputs[o];
    if (out.path.empty()) continue;
    CheckWritable(out);
    for (const NamedPath& in : inputs)
      if (!in.path.empty() && SameFile(out.path, in.path))
        throw std::runtime_error(out.option + " " + out.path + ": is the same file as " +
                                 in.option + " " + in.path +
                                 "; an input is never overwritten: write elsewhere");
    for (size_t e = 0; e < o; ++e)
      if (!outputs[e].path.empty() && SameFile(out.path, outputs[e].path))
        throw std::runtime_error(out.option + " " + out.path + ": is the same file as " +
                                 outputs[e].option + " " + outputs[e].path +
                                 "; each output needs a file of its own");
  }
}

}  // namespace mocapd
