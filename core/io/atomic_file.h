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

// Clears what killed processes left beside `target`: hidden work files named
// ".<stem>.tmp<pid>_<n>..." (WriteFileAtomically) or ".<stem>.part<pid>_<n>..." (exports,
// core/pipeline/export.h) whose process <pid> is gone are removed, except that an export's
// ".old" copy is moved back to `target` when `target` itself is missing (a kill between the two
// renames of a folder replacement). Each folder is scanned once per process (the first write
// into it); WriteFileAtomically and the export sinks call this. Returns the entries handled;
// never throws.
int CleanStaleWorkFiles(const std::filesystem::path& target);

// Convenience: writes `bytes` to `target` atomically.
void WriteBytesAtomically(const std::filesystem::path& target, const std::string& bytes);

// Reads a whole file; throws Io naming the file when it is missing or unreadable.
std::string ReadFileBytes(const std::filesystem::path& path);

}  // namespace avatar
