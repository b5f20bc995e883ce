#pragma once
// `avatar-studio bench SUBJECT [options]`: speed measurements. Each subject (render, and later
// model, ...) is a function that parses its own flags, registered with
// AVATAR_REGISTER_BENCH_SUBJECT("name", "summary", RunBenchName) in any app source file.
// Every subject measures this machine's baseline (GEMM peak) in the same run and reports
// ratios, because the machines are shared and noisy. The measurements live in core/pipeline
// (benchmarks.h and the subject's own module); the app files parse flags and print.

#include <string>
#include <vector>

#include "app/commands.h"
#include "core/tools/benchmarks.h"

namespace avatar::app {

using BenchSubjectFn = int (*)(const std::vector<std::string>& args);

struct BenchSubject {
  const char* name;     // word after `bench`
  const char* summary;  // one line for `bench --help`
  BenchSubjectFn run;   // parses args (flags after the subject) and returns an exit code
};

// Registers a subject (see AVATAR_REGISTER_BENCH_SUBJECT). Returns true.
bool RegisterBenchSubject(const BenchSubject& subject);
// Registered subjects in registration order.
std::vector<BenchSubject> BenchSubjects();

// Dispatches `bench SUBJECT ...`; returns an exit code.
int RunBench(const std::vector<std::string>& args);

// The flags of a subject whose measurement options (core/pipeline) are complete as they stand:
// those options, then the common ones (threads, data folder, verbosity).
template <typename Bench>
struct BenchSubjectOptions {
  Bench bench;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    bench.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    bench.Validate();
    common.Validate();
  }
};

// Options of `bench render` (the measurement: core/tools/benchmarks.h): cases, repeats,
// batch, rays per work item.
using BenchRenderOptions = BenchSubjectOptions<RenderBenchmarkOptions>;

// Runs the render benchmark and prints a table; returns kExitOk. Throws avatar::Error.
int RunBenchRenderImpl(const BenchRenderOptions& options, RunContext& ctx);

// The body every subject's BenchSubjectFn shares: parse `Options` from args (no positionals),
// print help when asked, else run `impl(options, ctx)` under GuardedRun.
template <typename Options, typename Impl>
int RunBenchSubject(const std::vector<std::string>& args, const std::string& subject, const char* description,
                    Impl impl) {
  const std::string title = "bench " + subject;
  return GuardedRun(title.c_str(), [&] {
    Options options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio " + title + " [options]", description, &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.empty()) << title << " takes no positional arguments";
    return impl(options, ProcessContext());
  });
}

}  // namespace avatar::app

#define AVATAR_REGISTER_BENCH_SUBJECT(name, summary, fn) \
  static const bool avatar_bench_subject_registered_##fn = ::avatar::app::RegisterBenchSubject({name, summary, &fn})
