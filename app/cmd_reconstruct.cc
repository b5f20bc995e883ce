#include "app/cmd_reconstruct.h"

#include <algorithm>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "core/io/image_io.h"
#include "core/pipeline/quality.h"
#include "core/pipeline/source_analysis.h"
#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar::app {

void ReconstructOptions::Validate() const {
  AVATAR_CHECK_OPTION(!input.empty()) << "missing IMAGE: give the portrait photo to reconstruct";
  AVATAR_CHECK_OPTION(!output.empty()) << "--output must not be empty";
  if (!quality.empty()) QualityPresetByName(quality);
  session.Validate();
  refine.Validate();
  common.Validate();
}

int RunReconstructImpl(const ReconstructOptions& options, RunContext& ctx) {
  options.Validate();
  SessionOptions so = options.session;
  so.data_dir = options.common.data_dir;
  Timer timer;
  Session session(so);
  const ModelInfo info = session.Info();
  if (so.random_weights && so.checkpoint.empty()) {
    std::cerr << "warning: running the UNTRAINED network with random weights (config " << info.config_name << ", seed "
              << so.seed << "); the avatar will look like noise.\n";
  }
  const cv::Mat image = LoadImageBgr(options.input);
  RefineOptions refine = options.refine;
  refine.data_dir = options.common.data_dir;
  if (!options.quality.empty()) {
    const QualityPreset& preset = QualityPresetByName(options.quality);
    if (!refine.Enabled()) refine = preset.Refine(refine);
    const std::filesystem::path cache = QualityCachePath(options.common.data_dir);
    bool measured = false;
    if (!ReadCachedQualityEstimates(cache, info.model_id, QualityEstimateThreads())) {
      std::cout << "Measuring the quality ladder on this machine (first use of this model at "
                << QualityEstimateThreads() << " threads; cached in '" << cache.string() << "')...\n"
                << std::flush;
    }
    const QualityEstimates estimates = CachedOrMeasuredQualityEstimates(session, cache, ctx, refine, &measured);
    std::cout << "Quality '" << preset.name << "' (" << preset.Describe(info) << "): "
              << FormatQualityEstimate(estimates.Find(preset.name)) << " (" << (measured ? "measured now" : "cached")
              << "; face analysis comes on top).\n";
  }
  // Face-analysis refusals (no face, too small, turned too far) name the photo.
  auto analyse = [&](auto&& run) {
    try {
      return run();
    } catch (const InvalidInput& e) {
      throw InvalidInput("'" + options.input + "': " + e.what());
    }
  };
  Avatar avatar;
  if (!refine.Enabled()) {
    avatar = analyse([&] { return session.Reconstruct(image, ctx); });
  } else {
    SourceAnalysis analysis;
    {
      RunContext::ProgressRange range(ctx, 0.0, 0.4);
      analysis = analyse([&] { return AnalyseSource(image, so.data_dir, ctx); });
    }
    {
      RunContext::ProgressRange range(ctx, 0.4, 0.5);
      avatar = session.ReconstructFromAnalysis(analysis.portrait, analysis.fit, ctx);
    }
    RunContext::ProgressRange range(ctx, 0.5, 1.0);
    const RefineResult r = RefineAvatar(session, avatar, analysis, refine, ctx);
    avatar = r.avatar;
    std::ostringstream line;
    line << std::fixed << std::setprecision(2) << "Refined the planes on the source view: " << r.steps << " steps in "
         << r.seconds << " s (stopped by " << r.stopped_by << "), source-view PSNR " << r.psnr_before << " -> "
         << r.psnr_after << " dB (masked by the matte, " << info.render_size << " px render).\n";
    std::cout << line.str();
  }
  session.SaveAvatar(avatar, options.output);
  std::cout << "Reconstructed '" << options.input << "' with the " << DescribeModel(info) << " in " << timer.Seconds()
            << " s and wrote '" << options.output << "'.\n";
  return kExitOk;
}

int RunReconstruct(const std::vector<std::string>& args) {
  return GuardedRun("reconstruct", [&] {
    ReconstructOptions options;
    std::vector<std::string> positionals;
    std::string description =
        "Finds the face, fits the morphable model and reconstructs the avatar's tri-planes\n"
        "(canonical + appearance), saved for `avatar-studio render` and the studio.";
    // The ladder's estimates are looked up only for the help text.
    if (std::find(args.begin(), args.end(), "--help") != args.end() ||
        std::find(args.begin(), args.end(), "-h") != args.end()) {
      description += "\n\n" + QualityLadderHelp();
    }
    if (!ParseCommand(options, args, "avatar-studio reconstruct IMAGE -o FILE.avatar [options]", description,
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.size() <= 1) << "expected one IMAGE, got " << positionals.size() << " arguments";
    if (!positionals.empty()) options.input = positionals[0];
    return RunReconstructImpl(options, ProcessContext());
  });
}

AVATAR_REGISTER_COMMAND("reconstruct", "reconstruct an avatar from a portrait", RunReconstruct);

}  // namespace avatar::app
