#include "core/io/resources.h"

#include <cstdlib>

namespace avatar {

std::vector<std::filesystem::path> ResourceCandidates(const std::string& relative) {
  std::vector<std::filesystem::path> out;
  if (const char* env = std::getenv("AVATAR_RESOURCE_DIR"); env != nullptr && env[0] != '\0') {
    out.push_back(std::filesystem::path(env) / relative);
    return out;
  }
  if (const auto installed = InstalledDataDir(); !installed.empty()) out.push_back(installed / relative);
  out.push_back(std::filesystem::path(AVATAR_SOURCE_DIR) / "resources" / relative);
  return out;
}

std::filesystem::path InstalledDataDir() {
  std::error_code ec;
  const auto exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) return {};
  return exe.parent_path().parent_path() / "share" / "avatar-studio";
}

std::filesystem::path ResourcePath(const std::string& relative) {
  const std::vector<std::filesystem::path> candidates = ResourceCandidates(relative);
  for (const auto& path : candidates) {
    std::error_code ec;
    if (std::filesystem::exists(path, ec)) return path;
  }
  return candidates.back();
}

}  // namespace avatar
