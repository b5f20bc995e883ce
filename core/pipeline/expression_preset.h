#pragma once
// Expression preset files: what the studio's expression panel saves and loads (Save... /
// Load...). A preset is JSON of the form {"expression": {"smile": 0.4, "jawOpen": 0.75}}: named
// expression controls with values in [0,1]. The parsing lives here, without Qt, so that it is
// tested and fuzzed on its own (tests/pipeline/expression_preset_test.cc, tests/fuzz
// presets_fuzz.cc); ui/ only calls it.

#include <filesystem>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "core/pipeline/expression.h"

namespace avatar {

// Parses the text of a preset. `source` names the file in every message. `known_controls`: the
// control names accepted (empty = any non-empty name). Values outside [0,1] are clamped to it
// (the sliders' range). Throws InvalidInput naming `source` for text that is not JSON, JSON of
// another shape, a value that is not a finite number, an empty or unknown control name.
Expression ParseExpressionPreset(std::string_view text, const std::string& source,
                                 const std::vector<std::string>& known_controls);

// Reads and parses the preset file `path`. Throws Io (unreadable file, naming it) or
// InvalidInput as ParseExpressionPreset.
Expression LoadExpressionPreset(const std::filesystem::path& path, const std::vector<std::string>& known_controls);

// The text of a preset holding `controls` (every entry, zeros included), pretty-printed.
std::string ExpressionPresetText(const std::map<std::string, double>& controls);

// Writes the preset atomically (temp file + rename). Throws Io naming the file.
void SaveExpressionPreset(const std::filesystem::path& path, const std::map<std::string, double>& controls);

}  // namespace avatar
