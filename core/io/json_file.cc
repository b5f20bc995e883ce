#include "core/io/json_file.h"

#include "core/io/atomic_file.h"
#include "core/util/error.h"

namespace avatar {

nlohmann::json ReadJsonFile(const std::filesystem::path& path, const std::string& remedy) {
  const std::string bytes = ReadFileBytes(path);
  try {
    return nlohmann::json::parse(bytes);
  } catch (const nlohmann::json::exception& e) {
    throw InvalidInput(path.string() + " is not valid JSON (" + e.what() + "): " + remedy);
  }
}

}  // namespace avatar
