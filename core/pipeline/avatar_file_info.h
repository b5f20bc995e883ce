#pragma once
// What an avatar file says about itself without loading it (plain types; the format is
// avatar_file.h, which implements this).

#include <filesystem>
#include <string>

namespace avatar {

// Which model an avatar file was made with (from its metadata).
struct AvatarFileInfo {
  std::string model_id;     // as ModelInfo::model_id
  std::string config_name;  // e.g. "lite"
};
// Throws Io (missing) or ModelLoad (not an avatar file, damaged).
AvatarFileInfo ReadAvatarFileInfo(const std::filesystem::path& path);

}  // namespace avatar
