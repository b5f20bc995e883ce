#pragma once
// Small helpers every command shares: number formatting for tables, comma lists, the process's
// peak memory, medians and the --expr name=value flags.

#include <map>
#include <string>
#include <vector>

#include "core/pipeline/expression.h"

namespace avatar::app {

// `value` with exactly `digits` decimals ("%.*f").
std::string Fixed(double value, int digits);

// "a,b,,c" -> {"a", "b", "c"} (empty items dropped).
std::vector<std::string> SplitList(const std::string& text);

// Peak resident memory of this process so far, in MB (getrusage's ru_maxrss).
double PeakRssMb();

// Median of `values` (the mean of the middle two for an even count). Throws InvalidInput when empty.
double Median(std::vector<double> values);

// The repeatable --expr flag: "name=value" entries -> named expression controls. Throws
// InvalidOptions for an entry without a name or value, a value that is not a number, or a
// non-finite value.
std::map<std::string, float> ParseControlFlags(const std::vector<std::string>& entries);
// ParseControlFlags as an Expression (relative to the portrait's fit).
Expression ParseExpressionFlags(const std::vector<std::string>& entries);

}  // namespace avatar::app
