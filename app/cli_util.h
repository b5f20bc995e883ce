#pragma once
// Small helpers every command shares: number formatting for tables, comma lists, the process's
// peak memory, medians (core/util/text.h, core/util/measure.h) and the --expr name=value
// flags.

#include <map>
#include <ostream>
#include <string>
#include <vector>

#include "core/pipeline/expression.h"
#include "core/util/measure.h"
#include "core/util/text.h"

namespace avatar::app {

// Fixed and SplitList (core/util/text.h), PeakRssMb and Median (core/util/measure.h).
using avatar::Fixed;
using avatar::Median;
using avatar::PeakRssMb;
using avatar::SplitList;

// The repeatable --expr flag: "name=value" entries -> named expression controls. Throws
// InvalidOptions for an entry without a name or value, a value that is not a number, or a
// non-finite value.
std::map<std::string, float> ParseControlFlags(const std::vector<std::string>& entries);
// ParseControlFlags as an Expression (relative to the portrait's fit).
Expression ParseExpressionFlags(const std::vector<std::string>& entries);

// A flag renamed in 0.2 (issue 31, one word per idea). The old name keeps working for one
// release: RewriteRenamedFlags replaces it and warns.
struct RenamedFlag {
  const char* command;   // the command words it belongs to, e.g. "animate" or "bench render"
  const char* old_flag;  // e.g. "--preset"
  const char* new_flag;  // e.g. "--config"
};

// The table of renamed flags (the one place to add or retire one).
const std::vector<RenamedFlag>& RenamedFlags();

// The release after which the old names of RenamedFlags() are removed ("0.2").
inline constexpr const char* kRenamedFlagsRemovedAfter = "0.2";

// `args` (a command line after the program name: command words, then flags) with each old flag
// of its command replaced by the new name, as "--old VALUE" or "--old=VALUE", before "--" only.
// Writes one line per replacement to `warnings`, e.g.
//   warning: `animate --preset` is deprecated and will be removed after 0.2; use --config
std::vector<std::string> RewriteRenamedFlags(const std::vector<std::string>& args, std::ostream& warnings);

}  // namespace avatar::app
