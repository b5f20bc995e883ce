#pragma once
// Small helpers every command shares: number formatting for tables, comma lists, the process's
// peak memory, medians (these four from core/pipeline/benchmarks.h) and the --expr name=value
// flags.

#include <map>
#include <string>
#include <vector>

#include "core/pipeline/benchmarks.h"
#include "core/pipeline/expression.h"

namespace avatar::app {

// Fixed, SplitList, PeakRssMb and Median: core/pipeline/benchmarks.h (the measurements use them too).
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

}  // namespace avatar::app
