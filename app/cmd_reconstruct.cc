#include "app/cmd_reconstruct.h"

#include <algorithm>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "core/io/image_io.h"
#include "core/pipeline/quality.h"
#include "core/pipeline/reconstruct.h"
#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar::app {

void ReconstructOptions::Validate() const {
  AVATAR_CHECK_OPTION(!input.empty()) << "missing IMAGE: give the portrait photo to reconstruct";
  AVATAR_CHECK_OPTION(!output.empty()) << "--output must not be empty";
  if (!quality.empty()) QualityLevelByName(quality);
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
  ReconstructionOptions ro;
  ro.quality = options.quality;
  ro.refine = options.refine;
  ro.data_dir = options.common.data_dir;
  if (!options.quality.empty()) {
    const QualityLevel& level = QualityLevelByName(options.quality);
    const std::filesystem::path cache = QualityCachePath(options.common.data_dir);
    bool measured = false;
    if (!ReadCachedQualityEstimates(cache, info.model_id, QualityEstimateThreads())) {
      std::cout << "Measuring the quality ladder on this machine (first use of this model at "
                << QualityEstimateThreads() << " threads; cached in '" << cache.string() << "')...\n"
                << std::flush;
    }
    const QualityEstimates estimates =
        CachedOrMeasuredQualityEstimates(session, cache, ctx, EffectiveRefinement(ro), &measured);
    std::cout << "Quality '" << level.name << "' (" << level.Describe(info) << "): "
              << FormatQualityEstimate(estimates.Find(level.name)) << " (" << (measured ? "measured now" : "cached")
              << "; face analysis comes on top).\n";
  }
  Reconstruction r;
  try {
    r = ReconstructPortrait(session, image, ro, ctx);
  } catch (const InvalidInput& e) {
    // Face-analysis refusals (no face, too small, turned too far) name the photo.
    throw InvalidInput("'" + options.input + "': " + e.what());
  }
  const Avatar& avatar = r.avatar;
  if (r.refinement) {
    std::ostringstream line;
    line << std::fixed << std::setprecision(2) << "Refined the planes on the source view: " << r.refinement->steps
         << " steps in " << r.refinement->seconds << " s (stopped by " << r.refinement->stopped_by
         << "), source-view PSNR " << r.refinement->psnr_before << " -> " << r.refinement->psnr_after
         << " dB (masked by the matte, " << info.render_size << " px render).\n";
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
