#pragma once
// Writing outputs safely: everything goes to a temporary file next to the target and is
// renamed over it only on success, so a failure or a cancel never leaves a half file
// under the target name.

#include <filesystem>
#include <functional>
#include <string>

namespace avatar {

// Calls `write(temp_path)`, then renames temp_path to `target`. If `write` throws, the
// temporary file is removed and the exception propagates. Throws Io when the target's
// folder does not exist or the rename fails.
void WriteFileAtomically(const std::filesystem::path& target,
                         const std::function<void(const std::filesystem::path& temp_path)>& write);

// Convenience: writes `bytes` to `target` atomically.
void WriteBytesAtomically(const std::filesystem::path& target, const std::string& bytes);

// Reads a whole file; throws Io naming the file when it is missing or unreadable.
std::string ReadFileBytes(const std::filesystem::path& path);

}  // namespace avatar
