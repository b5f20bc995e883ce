#include "app/cmd_bench.h"

#include <iostream>
#include <sstream>

#include "app/cli_util.h"
#include "core/util/error.h"
#include "core/util/options.h"

namespace avatar::app {

namespace {

std::vector<BenchSubject>& SubjectRegistry() {
  static std::vector<BenchSubject> registry;
  return registry;
}

void PrintBenchHelp() {
  std::cout << "Usage: avatar-studio bench SUBJECT [options]\n\nSubjects:\n";
  for (const auto& s : BenchSubjects()) {
    std::string name = s.name;
    name.resize(12, ' ');
    std::cout << "  " << name << s.summary << "\n";
  }
  std::cout << "\nRun 'avatar-studio bench SUBJECT --help' for a subject's options.\n";
}

int RunBenchRender(const std::vector<std::string>& args) {
  return RunBenchSubject<BenchRenderOptions>(
      args, "render",
      "Times the volume renderer (random tri-planes and decoder, deterministic sampling, no\n"
      "gradients) and compares the decoder's FLOP rate with this machine's GEMM peak.",
      RunBenchRenderImpl);
}

}  // namespace

bool RegisterBenchSubject(const BenchSubject& subject) {
  SubjectRegistry().push_back(subject);
  return true;
}

std::vector<BenchSubject> BenchSubjects() { return SubjectRegistry(); }

int RunBench(const std::vector<std::string>& args) {
  if (args.empty() || args[0] == "--help" || args[0] == "-h" || args[0] == "help") {
    PrintBenchHelp();
    return args.empty() ? kExitUsage : kExitOk;
  }
  for (const auto& s : BenchSubjects()) {
    if (args[0] == s.name) return s.run(std::vector<std::string>(args.begin() + 1, args.end()));
  }
  std::cerr << "avatar-studio bench: unknown subject '" << args[0] << "'\n";
  PrintBenchHelp();
  return kExitUsage;
}

int RunBenchRenderImpl(const BenchRenderOptions& options, RunContext& ctx) {
  options.Validate();
  const auto print_header = [&](const RenderBenchmarkReport& r) {
    std::cout << "Render benchmark: " << r.threads << " threads, batch " << options.bench.batch << ", "
              << options.bench.repeats
              << " timed renders per case (median), float32, deterministic sampling, inference mode.\n"
              << "GEMM peak (fp32 1024^3, best of 5): " << Fixed(r.gemm_before, 1) << " GFLOP/s\n\n"
              << "| case | rays | samples/ray | planes | time (s) | rays/s | samples/s | plane sampling | decoder | "
                 "marching+other | decoder GFLOP/s | % of GEMM peak |\n"
              << "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  };
  double gemm_before = 0.0;
  const auto print_row = [&](const RenderBenchmarkRow& rc) {
    std::ostringstream row;
    row << "| " << rc.name << " | " << rc.batch << "x" << rc.resolution << "^2 | " << rc.num_coarse << "+"
        << rc.num_importance << " | 3x32x" << rc.plane_size << "^2 | " << Fixed(rc.median_seconds, 3) << " | "
        << Fixed(rc.rays_per_second / 1e3, 1) << "k | " << Fixed(rc.samples_per_second / 1e6, 2) << "M | "
        << Fixed(100.0 * rc.sample_share, 0) << "% | " << Fixed(100.0 * rc.decoder_share, 0) << "% | "
        << Fixed(100.0 * rc.other_share, 0) << "% | " << Fixed(rc.decoder_gflops, 1) << " | "
        << Fixed(100.0 * rc.decoder_gflops / gemm_before, 0) << "% |";
    std::cout << row.str() << std::endl;
  };
  const RenderBenchmarkReport report = RunRenderBenchmark(
      options.bench, options.common.threads, ctx,
      [&](const RenderBenchmarkReport& r) {
        gemm_before = r.gemm_before;
        print_header(r);
      },
      print_row);
  std::cout << "\nGEMM peak after the run: " << Fixed(report.gemm_after, 1)
            << " GFLOP/s (a large change means the machine was busy).\n"
            << "Stage shares are thread-summed times inside the renderer; decoder GFLOP/s = decoder FLOPs"
            << " (2 x (32x64 + 64x33) per point) / (thread-summed decoder time / threads).\n";
  return kExitOk;
}

AVATAR_REGISTER_COMMAND("bench", "measure the speed of the renderer and the model", RunBench);
AVATAR_REGISTER_BENCH_SUBJECT("render",
                              "volume renderer: rays/s, samples/s, stage shares, decoder GFLOP/s vs GEMM peak",
                              RunBenchRender);

}  // namespace avatar::app
