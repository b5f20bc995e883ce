// avatar-studio animate: portrait + driver (video or keyframes) -> MP4 or PNG sequence.
#include <iostream>

#include "app/commands.h"
#include "core/pipeline/animate.h"
#include "core/util/error.h"
#include "core/util/options.h"

namespace avatar::app {
namespace {

struct AnimateCommandOptions {
  // What to animate, how and where to.
  AnimateOptions animate;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    animate.Visit(v);
    common.Visit(v);
  }
};

int RunAnimate(const std::vector<std::string>& args) {
  return GuardedRun("animate", [&] {
    AnimateCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio animate PORTRAIT [DRIVER] -o OUTPUT [options]",
                      "Animates the portrait with a driving video (expressions and head pose, audio kept) or\n"
                      "keyframes (.json), or turns it on a turntable (--view orbit), and writes an MP4 (H.264)\n"
                      "or a PNG sequence with alpha (output without .mp4 = a folder of frames).\n"
                      "The export is written to a temporary file and renamed when complete.",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.size() <= 2)
        << "expected PORTRAIT and at most one DRIVER, got " << positionals.size() << " arguments";
    if (!positionals.empty()) options.animate.source = positionals[0];
    if (positionals.size() > 1) options.animate.driver = positionals[1];
    options.animate.backend.data_dir = options.common.data_dir;
    std::cout << BackendStatement(options.animate.backend) << "\n";
    const AnimateResult r = RunAnimation(options.animate, ProcessContext());
    std::cout << "Wrote " << r.stats.frames << " frames at " << r.fps << " fps to '" << r.stats.output.string()
              << "'.\nFrames rendered by: " << r.source_label << "\n";
    if (!r.driver_note.empty()) std::cout << "Note: " << r.driver_note << ".\n";
    if (!options.animate.driver.empty() && !r.driver_measured) {
      std::cout << "Note: this build cannot measure the driving video's expressions (no face analysis); the\n"
                   "driver gave timing and audio only.\n";
    }
    return kExitOk;
  });
}

}  // namespace

AVATAR_REGISTER_COMMAND("animate", "drive an avatar with a video or keyframes and export a clip", RunAnimate);

}  // namespace avatar::app
