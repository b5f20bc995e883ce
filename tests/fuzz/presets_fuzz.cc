// Fuzz target "presets": expression preset JSON (the studio's Load... of the expression panel),
// core/pipeline/expression_preset ParseExpressionPreset, with and without a list of known
// controls. A preset that loads must hold finite values in [0,1] and survive a save/parse round
// trip unchanged.
#include <cmath>
#include <stdexcept>

#include "core/pipeline/expression_preset.h"
#include "core/util/error.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

const std::vector<std::string>& Known() {
  static const std::vector<std::string> names = {"jawOpen", "smile", "frown", "pucker", "mouthWide",
                                                 "browRaise", "browFrown", "blinkLeft", "blinkRight", "eyesWide"};
  return names;
}

void CheckLoaded(const Expression& e) {
  std::map<std::string, double> saved;
  for (const auto& [name, value] : e.controls) {
    if (!std::isfinite(value) || value < 0.0f || value > 1.0f) {
      throw std::logic_error("a loaded preset holds a value outside [0,1]");
    }
    saved[name] = value;
  }
  if (ParseExpressionPreset(ExpressionPresetText(saved), "round-trip.json", {}) != e) {
    throw std::logic_error("an expression preset changes in a save/load round trip");
  }
}

std::string RunPresets(std::string_view input) {
  const std::string any = AcceptAvatarErrors([&] { CheckLoaded(ParseExpressionPreset(input, "preset.json", {})); });
  const std::string known =
      AcceptAvatarErrors([&] { CheckLoaded(ParseExpressionPreset(input, "preset.json", Known())); });
  return known.empty() ? any : known;
}

int PresetsSeeds(const std::filesystem::path& dir) {
  WriteFile(dir / "happy.json", ExpressionPresetText({{"smile", 0.4}, {"jawOpen", 0.75}, {"browRaise", 0.0}}));
  WriteFile(dir / "all.json", ExpressionPresetText({{"jawOpen", 0.1}, {"smile", 0.2}, {"frown", 0.3}, {"pucker", 0.4},
                                                    {"mouthWide", 0.5}, {"browRaise", 0.6}, {"browFrown", 0.7},
                                                    {"blinkLeft", 0.8}, {"blinkRight", 0.9}, {"eyesWide", 1.0}}));
  WriteFile(dir / "neutral.json", R"({"expression": {}})");
  WriteFile(dir / "edge-clamped.json", R"({"expression": {"smile": 7, "frown": -1e300}})");
  return 4;
}

AVATAR_FUZZ_TARGET("presets", RunPresets, PresetsSeeds);

}  // namespace
}  // namespace avatar::fuzz
