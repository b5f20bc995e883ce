#pragma once
// Reading JSON files with an error that names the file and what to do.

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

namespace avatar {

// The parsed contents of `path`. Throws Io when it cannot be read, InvalidInput "<path> is not
// valid JSON (<parser message>): <remedy>" when it does not parse.
nlohmann::json ReadJsonFile(const std::filesystem::path& path, const std::string& remedy);

}  // namespace avatar
