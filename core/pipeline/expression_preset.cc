#include "core/pipeline/expression_preset.h"

#include <algorithm>
#include <cmath>

#include <nlohmann/json.hpp>

#include "core/io/atomic_file.h"
#include "core/util/error.h"

namespace avatar {

Expression ParseExpressionPreset(std::string_view text, const std::string& source,
                                 const std::vector<std::string>& known_controls) {
  const std::string what = "expression preset '" + source + "'";
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text.begin(), text.end());
  } catch (const nlohmann::json::exception& e) {
    throw InvalidInput(what + " is not valid JSON: " + e.what());
  }
  AVATAR_CHECK_INPUT(j.is_object() && j.contains("expression") && j.at("expression").is_object())
      << what << " must be {\"expression\": {\"smile\": 0.5, ...}}";
  Expression e;
  const nlohmann::json& controls = j.at("expression");
  for (auto it = controls.begin(); it != controls.end(); ++it) {
    AVATAR_CHECK_INPUT(!it.key().empty()) << what << ": a control without a name";
    // A number too large for a double is parsed as infinity; NaN is no JSON, but guard anyway.
    AVATAR_CHECK_INPUT(it->is_number() && std::isfinite(it->get<double>()))
        << what << ": '" << it.key() << "' must be a number in [0,1]";
    AVATAR_CHECK_INPUT(known_controls.empty() ||
                       std::find(known_controls.begin(), known_controls.end(), it.key()) != known_controls.end())
        << what << ": unknown control '" << it.key() << "'";
    e.controls[it.key()] = static_cast<float>(std::clamp(it->get<double>(), 0.0, 1.0));
  }
  return e;
}

Expression LoadExpressionPreset(const std::filesystem::path& path, const std::vector<std::string>& known_controls) {
  return ParseExpressionPreset(ReadFileBytes(path), path.string(), known_controls);
}

std::string ExpressionPresetText(const std::map<std::string, double>& controls) {
  nlohmann::json j;
  j["expression"] = nlohmann::json::object();
  for (const auto& [name, value] : controls) j["expression"][name] = value;
  return j.dump(2) + "\n";
}

void SaveExpressionPreset(const std::filesystem::path& path, const std::map<std::string, double>& controls) {
  WriteBytesAtomically(path, ExpressionPresetText(controls));
}

}  // namespace avatar
