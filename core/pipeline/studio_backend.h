#pragma once
// The one place that decides what renders the head for a portrait, shared by the studio
// and the command line. The choice is honest and every frame source says what it is:
//  - renderer "neural" (the default): the neural avatar of the trained model (the bundled
//    default, the user's installed one or --checkpoint), labelled with DescribeModel();
//  - random weights only on explicit request (labelled "random weights, not a result");
//  - renderer "morphable", or a default model that cannot be loaded: the textured
//    morphable-model preview, labelled as a preview with the reason.

#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/pipeline/driving.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/session.h"
#include "core/util/run_context.h"

namespace avatar {

struct SourceAnalysis;  // source_analysis.h

struct BackendOptions {
  // What renders the head: "neural" (the trained GOHA model) or "morphable" (the preview).
  std::string renderer = "neural";
  // Model checkpoint for the neural renderer ("" = installed or bundled default, see
  // SessionOptions::checkpoint). An explicit checkpoint that fails to load is an error, never
  // a silent fallback to the preview.
  std::string checkpoint;
  // Network size (model config) of --random-weights: "lite" (fast, CPU-sized) or "paper".
  std::string config = "lite";
  // Use the neural network with random weights (a plumbing check, never a result).
  bool random_weights = false;
  // Folder with the installed models ("" = AVATAR_DATA_DIR or ~/.cache/avatar-studio).
  std::string data_dir;
  // Quality level of the neural avatar (quality.h: its render settings and refinement); "" =
  // the one-shot planes rendered at the model's size (SR when trained).
  std::string quality;
  // The photo's own detail over the neural head (detail_source.h): "head" (the photo warped
  // onto the face through the face mesh and onto hair, ears and neck through the network's
  // depth, where it saw the surface, finished by the fusion net: FusionWeightsOf), "geometric"
  // (the same without the fusion net: the geometric composite), "face" (the face only) or "off"
  // (the network alone).
  std::string detail = "head";
  // Weights of the fusion net that finishes each detail frame ("" = with --detail head the
  // bundled one, FusionWeightsOf; otherwise none).
  std::string fusion;
  // With the detail path: the network encodes a new expression on every Nth frame at most, the
  // photo's face follows every frame (DetailOptions::base_expression_every; live's default 3).
  int network_expression_every = 1;
  // With the head detail: move the network's depth onto the fitted face mesh, reaching this
  // fraction of the image height from the face (0 = the whole head; < 0 = off, the default;
  // DetailOptions::align_depth_to_face and align_depth_reach).
  double align_depth = -1.0;

  template <typename V>
  void Visit(V&& v) {
    v("renderer", renderer, "What renders the head: neural (the trained model) or morphable (the preview)");
    v("checkpoint", checkpoint,
      "Neural model checkpoint (default: <data dir>/models/goha.ckpt if installed, else the bundled model)");
    v("config", config, "Network size with --random-weights: lite or paper");
    v("random_weights", random_weights,
      "Render with the untrained network's random weights (plumbing check; not a result)");
    v("quality", quality, "Quality level: instant, preview, standard, fine, best or paper (\"\" = standard frames, SR when trained)");
    v("detail", detail,
      "The photo's detail over the neural head: head (warped onto face, hair, ears and neck where the photo saw them, "
      "finished by the learned fusion net), geometric (the same without the net), face (the face only) or off");
    v("fusion", fusion,
      "Fusion net weights that finish each detail frame (\"\" = the bundled net with --detail head, none otherwise)");
    v("network_expression_every", network_expression_every,
      "With the detail path, the network takes a new expression on every Nth frame at most (faster; the photo's "
      "face follows every frame)");
    v("align_depth", align_depth,
      "With the head detail, move the network's depth onto the fitted face mesh, reaching this fraction of the "
      "image height from the face (0 = the whole head; < 0 = off)");
  }
  // Throws InvalidOptions for an unknown config, quality level or detail mode, --fusion with
  // --detail off or geometric.
  void Validate() const;
};

// The fusion weights that finish the detail frames of `options`: --fusion when given; with
// --detail head, the trained model (not --random-weights, which the net never saw) and no
// --fusion, the bundled net (ResourcePath(kBundledFusionFile)) when it is installed; else ""
// (the geometric composite). When the bundled net is missing, `note` (if given) says so and
// where it was looked for.
std::string FusionWeightsOf(const BackendOptions& options, std::string* note = nullptr);

// Builds the frame source for `portrait` (BGR8). Reports stages through ctx and honours
// cancel. Throws InvalidInput (no face), MissingData (models not installed), Cancelled.
std::shared_ptr<const FrameSource> CreateFrameSource(const cv::Mat& portrait, const BackendOptions& options,
                                                     RunContext& ctx);

// Every path that can render one portrait, from one analysis (for comparisons of the paths):
// the neural avatar alone, the same avatar under the photo's detail path (face only, and
// head), and the morphable preview. The neural model must load (no fallback). Throws like
// CreateFrameSource.
struct PortraitPaths {
  std::shared_ptr<const FrameSource> network;
  // The detail paths are DetailFrameSource (detail_source.h; not included here: the GUI includes
  // this header after Qt and must not see LibTorch's headers).
  std::shared_ptr<const FrameSource> face;     // the detail path on the face only
  std::shared_ptr<const FrameSource> detail;   // the detail path on the head (the default)
  std::shared_ptr<const FrameSource> learned;  // the same finished by the fusion net (FusionWeightsOf(options), if any)
  std::shared_ptr<const FrameSource> preview;
  face::AlignedPortrait portrait;  // the photo's aligned crop, matte and masks they were built from
  double bake_seconds = 0.0;       // building the head detail path (its source-view depth bakes)
};
PortraitPaths CreatePortraitPaths(const cv::Mat& portrait, const BackendOptions& options, RunContext& ctx);
// The same from a portrait analysed before (AnalyseSource, or AnalysisFromFit of a stored item).
PortraitPaths CreatePortraitPaths(SourceAnalysis analysis, const BackendOptions& options, RunContext& ctx);

// A loaded avatar (Session::LoadAvatar) as a frame source: the network renders it (with
// `settings` when given, else as the studio does), wrapped in the photo's detail path
// (options.detail, options.fusion) when the avatar keeps its portrait's analysis
// (Avatar::HasPortraitAnalysis). An avatar without one renders with the network alone and the
// source's Warnings() say why. Throws MissingData (morphable model not installed), ModelLoad
// (fusion weights), InvalidInput (a stored analysis that does not fit the morphable model).
std::shared_ptr<const FrameSource> SavedAvatarSource(std::shared_ptr<const Session> session, const Avatar& avatar,
                                                     const BackendOptions& options,
                                                     const RenderSettings* settings = nullptr);

// The frame source of a portrait photo (CreateFrameSource) or of a saved FILE.avatar
// (SavedAvatarSource, with the session these options select), by the file's extension. Errors
// name the file. Throws like those two and LoadImageBgr.
std::shared_ptr<const FrameSource> OpenAvatarSource(const std::string& input, const BackendOptions& options,
                                                    RunContext& ctx);

// The analyser for driving videos (face tracking + morphable fit), or a factory returning
// null when this build cannot measure driving frames.
FrameAnalyzerFactory DrivingAnalyzers(const BackendOptions& options);

// A short sentence for the user about what will render the frames (before a portrait is
// loaded; the frame source's Label() is the final word).
std::string BackendStatement(const BackendOptions& options);

// The neural session these options select, shared per checkpoint and data folder (loading it is
// the slow part). Throws MissingData / ModelLoad as Session does.
std::shared_ptr<const Session> SharedSession(const BackendOptions& options);

}  // namespace avatar
