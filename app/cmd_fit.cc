// `avatar-studio fit IMAGE [--expr name=value ...] --out-dir DIR`: fits the morphable face model
// to the portrait's aligned 512 crop and writes the overlay, I_exp (source and edited
// expression at the frontal camera), I_neu / M_neu (neutral at the source camera) and a JSON
// with coefficients, camera label and fit error.

#include <iomanip>
#include <iostream>

#include "app/cli_util.h"
#include "app/cmd_bench.h"
#include "app/commands.h"
#include "core/tools/benchmarks.h"
#include "core/tools/portrait_fit.h"
#include "core/util/error.h"
#include "core/util/threads.h"

namespace avatar::app {
namespace {

struct FitCommandOptions {
  // Portrait (positional), output folder, render size, faces, model file, fitting, texture.
  PortraitFitOptions fit;
  // Expression edits "name=value" (repeatable), added to the fitted expression for I_exp_edited.
  std::vector<std::string> expr;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("out_dir", fit.out_dir, "Output folder", 'o');
    v("expr", expr, "Expression edit name=value (repeatable), e.g. --expr jawOpen=0.8");
    v("size", fit.size, "Side of the rendered images in pixels");
    v("supersample", fit.supersample, "Supersampling factor of the renders");
    v("face_index", fit.face_index, "Face to fit: -1 = main face, k = k-th detected face");
    v("all_faces", fit.all_faces, "Fit every detected face and print a table of reprojection errors");
    v("model", fit.model, "Morphable model file (default: the bundled model)");
    fit.fit.Visit(v);
    fit.texture.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    fit.Validate();
    common.Validate();
  }
};

int RunFitImpl(const FitCommandOptions& o, RunContext& ctx) {
  o.Validate();
  PortraitFitOptions fit = o.fit;
  fit.data_dir = o.common.data_dir;
  fit.edits = ParseControlFlags(o.expr);
  std::cout << std::fixed << std::setprecision(2);
  FitPortrait(fit, ctx, [&](const FaceFitOutcome& r) {
    if (r.skipped) {
      std::cout << "face " << r.face_index << ": skipped (" << r.skip_reason << ")\n";
      return;
    }
    std::cout << (o.fit.all_faces ? "face " + std::to_string(r.face_index) + ": " : std::string())
              << "reprojection error " << r.fit.mean_error_px << " px = " << r.fit.mean_error_iod * 100
              << "% of the inter-ocular distance (" << r.fit.inter_ocular_px << " px); wrote " << r.dir << "\n";
  });
  return kExitOk;
}

int RunFit(const std::vector<std::string>& args) {
  return GuardedRun("fit", [&] {
    FitCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio fit IMAGE [--expr name=value ...] --out-dir DIR",
                      "Fits the morphable face model to the portrait and writes overlay.png, I_exp_source.png,\n"
                      "I_exp_edited.png, I_neu.png, M_neu.png and fit.json (coefficients, camera label, error).\n"
                      "Expression controls: jawOpen smile frown pucker mouthWide browRaise browFrown blinkLeft\n"
                      "blinkRight eyesWide.",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.size() == 1) << "expected one IMAGE, got " << positionals.size() << " arguments";
    options.fit.input = positionals[0];
    return RunFitImpl(options, ProcessContext());
  });
}

// `avatar-studio bench morphable`: fitting, texture and rendering speed on synthetic landmarks of
// the committed model (no face analysis), as milliseconds and as multiples of one fp32
// 1024^3 GEMM measured in the same run. Flags: repetitions and frames of the sequence fit.
using BenchMorphableOptions = BenchSubjectOptions<MorphableBenchmarkOptions>;

int RunBenchMorphableImpl(BenchMorphableOptions o, RunContext& ctx) {
  o.Validate();
  o.bench.data_dir = o.common.data_dir;
  const MorphableBenchmarkReport r = RunMorphableBenchmark(o.bench, ctx);
  std::cout << "Morphable benchmark: " << ConfiguredThreads() << " threads, model with " << r.identity_components
            << " identity + " << r.expression_components << " expression components, median of " << o.bench.repeats
            << " runs after a warm-up.\nBaseline: fp32 GEMM " << std::fixed << std::setprecision(1) << r.gemm_gflops
            << " GFLOP/s, one 1024^3 GEMM = " << std::setprecision(2) << r.gemm_ms << " ms\n\n"
            << "| stage | time (ms) | in 1024^3 GEMMs |\n|---|---|---|\n";
  auto row = [&](const char* name, double ms) {
    std::cout << "| " << name << " | " << std::setprecision(2) << ms << " | " << std::setprecision(1) << ms / r.gemm_ms
              << " |\n";
  };
  row("Fit (one 512 crop, 468 landmarks)", r.fit_ms);
  row("SampleTexture (256^2 UV)", r.texture_ms);
  row("Render 512^2 (I_neu)", r.render_ms);
  row("Render 512^2, 2x2 supersampling", r.render_supersampled_ms);
  row("Render 256^2 (I_exp)", r.render_256_ms);
  row(("FitSequence per frame (" + std::to_string(o.bench.frames) + " frames)").c_str(), r.sequence_ms_per_frame);
  return kExitOk;
}

int RunBenchMorphable(const std::vector<std::string>& args) {
  return RunBenchSubject<BenchMorphableOptions>(
      args, "morphable", "Speed of fitting, texture sampling and the CPU mesh renderer.", RunBenchMorphableImpl);
}

}  // namespace

AVATAR_REGISTER_BENCH_SUBJECT("morphable", "morphable model: fit, texture and mesh rendering speed", RunBenchMorphable);

AVATAR_REGISTER_COMMAND("fit", "fit the morphable face model to a portrait", RunFit);

}  // namespace avatar::app
