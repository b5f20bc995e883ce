#pragma once
// Measuring on shared, noisy machines: medians of repeated runs, the process's peak memory and
// the machine's fp32 GEMM rate, which every benchmark measures in the same run as its baseline.

#include <cstdint>
#include <functional>
#include <vector>

#include "core/util/run_context.h"

namespace avatar {

// Median of `values` (the mean of the middle two for an even count). Throws InvalidInput when empty.
double Median(std::vector<double> values);
// Mean of `values`; NaN when empty (a table cell with nothing measured).
double MeanOrNan(const std::vector<double>& values);

// Median wall time in seconds of `fn` over `repeats` runs after one warm-up run; checks `ctx`
// for a cancel before each timed run. Throws InvalidInput for repeats < 1.
double MedianSeconds(int repeats, RunContext& ctx, const std::function<void()>& fn);

// Peak resident memory of this process so far, in MB (getrusage's ru_maxrss).
double PeakRssMb();

// Measured fp32 GEMM rate of this machine with the current thread setting: the best of
// `repeats` n x n x n products (2 n^3 FLOPs each), in GFLOP/s.
double MeasureGemmGflops(int64_t n = 1024, int repeats = 5);

}  // namespace avatar
