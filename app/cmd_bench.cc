#include "app/cmd_bench.h"

#include <algorithm>
#include <cstdio>
#include <iostream>
#include <sstream>

#include "app/cli_util.h"
#include "core/model/triplane_decoder.h"
#include "core/render/renderer.h"
#include "core/util/error.h"
#include "core/util/options.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

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

// One render benchmark configuration.
struct RenderCase {
  const char* name;
  int resolution;
  int num_coarse;
  int num_importance;
  int plane_size;
};

const std::vector<RenderCase>& RenderCases() {
  static const std::vector<RenderCase> cases = {
      {"paper", 128, 48, 48, 256},  // the paper's render: 128^2 rays, 48 + 48 samples, 3x32x256^2 planes
      {"medium", 64, 48, 48, 256},
      {"small", 64, 24, 24, 128},
      {"tiny", 32, 12, 12, 64},
  };
  return cases;
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

double MeasureGemmGflops(int64_t n, int repeats) {
  torch::NoGradGuard no_grad;
  const torch::Tensor a = torch::randn({n, n});
  const torch::Tensor b = torch::randn({n, n});
  torch::Tensor c = torch::mm(a, b);  // warm-up (allocations, BLAS threads)
  double best = 0.0;
  for (int i = 0; i < repeats; ++i) {
    Timer timer;
    torch::mm_out(c, a, b);
    const double seconds = timer.Seconds();
    best = std::max(best, 2.0 * static_cast<double>(n) * n * n / seconds / 1e9);
  }
  return best;
}

void BenchRenderOptions::Validate() const {
  AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 100) << "--repeats must be 1..100, got " << repeats;
  AVATAR_CHECK_OPTION(batch >= 1 && batch <= 64) << "--batch must be 1..64, got " << batch;
  AVATAR_CHECK_OPTION(chunk_rays >= 1) << "--chunk-rays must be >= 1, got " << chunk_rays;
  for (const auto& name : SplitList(presets)) {
    bool known = name == "all";
    for (const auto& c : RenderCases()) known = known || name == c.name;
    AVATAR_CHECK_OPTION(known) << "unknown preset '" << name << "' (paper, medium, small, tiny, all)";
  }
  common.Validate();
}

int RunBenchRenderImpl(const BenchRenderOptions& options, RunContext& ctx) {
  options.Validate();
  const auto wanted = SplitList(options.presets);
  const bool all = std::find(wanted.begin(), wanted.end(), "all") != wanted.end();
  const int threads = ConfiguredThreads() > 0 ? ConfiguredThreads() : ConfigureThreads(options.common.threads);
  torch::InferenceMode inference;
  torch::manual_seed(0);

  const double gemm_before = MeasureGemmGflops();
  std::cout << "Render benchmark: " << threads << " threads, batch " << options.batch << ", " << options.repeats
            << " timed renders per preset (median), float32, deterministic sampling, inference mode.\n"
            << "GEMM peak (fp32 1024^3, best of 5): " << Fixed(gemm_before, 1) << " GFLOP/s\n\n"
            << "| preset | rays | samples/ray | planes | time (s) | rays/s | samples/s | plane sampling | decoder | "
               "marching+other | decoder GFLOP/s | % of GEMM peak |\n"
            << "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  std::vector<std::string> rows;
  for (const auto& rc : RenderCases()) {
    if (!all && std::find(wanted.begin(), wanted.end(), rc.name) == wanted.end()) continue;
    ctx.ThrowIfCancelled();
    render::RenderOptions ro;
    ro.resolution = rc.resolution;
    ro.num_coarse = rc.num_coarse;
    ro.num_importance = rc.num_importance;
    ro.chunk_rays = options.chunk_rays;
    const int64_t b = options.batch;
    TriplaneDecoder decoder;
    const torch::Tensor planes = torch::randn({b, 3, kDecoderInputChannels, rc.plane_size, rc.plane_size});
    const render::Cameras cameras = render::FrontalCameras(b);
    const render::PointDecoder decode = [&](const torch::Tensor& f) { return decoder->forward(f); };
    render::RenderOutput warm = render::RenderTriplanes(planes, decode, cameras, ro);
    AVATAR_CHECK(torch::isfinite(warm.features).all().item<bool>()) << "benchmark render produced non-finite values";
    std::vector<double> seconds;
    double sample_ns = 0, decode_ns = 0, total_ns = 0, points = 0;
    for (int i = 0; i < options.repeats; ++i) {
      ctx.ThrowIfCancelled();
      render::RenderProfile profile;
      Timer timer;
      render::RenderTriplanes(planes, decode, cameras, ro, c10::nullopt, &profile);
      seconds.push_back(timer.Seconds());
      sample_ns += static_cast<double>(profile.sample_ns.load());
      decode_ns += static_cast<double>(profile.decode_ns.load());
      total_ns += static_cast<double>(profile.total_ns.load());
      points += static_cast<double>(profile.points.load());
    }
    std::sort(seconds.begin(), seconds.end());
    const double median = seconds[seconds.size() / 2];
    const double rays = static_cast<double>(b) * rc.resolution * rc.resolution;
    const double samples = rays * (rc.num_coarse + rc.num_importance);
    // Thread-summed stage times; their wall share is the same fraction of the render.
    const double decode_wall = decode_ns * 1e-9 / threads / options.repeats;
    const double flops = decoder->FlopsPerPoint() * points / options.repeats;
    const double gflops = decode_wall > 0 ? flops / decode_wall / 1e9 : 0.0;
    std::ostringstream row;
    row << "| " << rc.name << " | " << b << "x" << rc.resolution << "^2 | " << rc.num_coarse << "+" << rc.num_importance
        << " | 3x32x" << rc.plane_size << "^2 | " << Fixed(median, 3) << " | " << Fixed(rays / median / 1e3, 1)
        << "k | " << Fixed(samples / median / 1e6, 2) << "M | " << Fixed(100.0 * sample_ns / total_ns, 0) << "% | "
        << Fixed(100.0 * decode_ns / total_ns, 0) << "% | "
        << Fixed(100.0 * (total_ns - sample_ns - decode_ns) / total_ns, 0) << "% | " << Fixed(gflops, 1) << " | "
        << Fixed(100.0 * gflops / gemm_before, 0) << "% |";
    std::cout << row.str() << std::endl;
  }
  const double gemm_after = MeasureGemmGflops();
  std::cout << "\nGEMM peak after the run: " << Fixed(gemm_after, 1)
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
