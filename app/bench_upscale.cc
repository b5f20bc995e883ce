// `avatar-studio bench upscale`: the 256 -> 512 step of exports (core/tools/upscale_benchmark.h):
// bicubic against the ESRGAN-family x2 upscaler on real validation frames, and both against
// rendering the detail path at 512 directly; writes upscale.md, upscale.json and upscale.png.

#include <iostream>

#include "app/cmd_bench.h"
#include "core/tools/upscale_benchmark.h"

namespace avatar::app {

namespace {

using BenchUpscaleOptions = BenchSubjectOptions<UpscaleBenchmarkOptions>;

int RunBenchUpscaleImpl(BenchUpscaleOptions options, RunContext& ctx) {
  options.Validate();
  options.bench.data_dir = options.common.data_dir;
  options.bench.threads = options.common.threads;
  const UpscaleBenchmarkReport r =
      RunUpscaleBenchmark(options.bench, ctx, [](const std::string& line) { std::cerr << line; });
  std::cout << r.markdown << "\nWrote " << r.markdown_path << ", " << r.json_path << " and " << r.image_path << ".\n";
  return kExitOk;
}

int RunBenchUpscale(const std::vector<std::string>& args) {
  return RunBenchSubject<BenchUpscaleOptions>(
      args, "upscale",
      "The 256 -> 512 step of exports: on a dataset's validation split, bicubic against the ESRGAN-family x2\n"
      "upscaler on real frames (half size and back), and both against rendering the detail path at full size;\n"
      "writes upscale.md, upscale.json and upscale.png (crops) into --out.",
      RunBenchUpscaleImpl);
}

}  // namespace

AVATAR_REGISTER_BENCH_SUBJECT("upscale", "the 256 -> 512 export step: bicubic vs the ESRGAN x2 upscaler vs detail at 512",
                              RunBenchUpscale);

}  // namespace avatar::app
