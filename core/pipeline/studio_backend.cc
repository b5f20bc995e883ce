#include "core/pipeline/studio_backend.h"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <mutex>

#include <opencv2/imgproc.hpp>

#include "core/face/face_analyzer.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/resources.h"
#include "core/morphable/morphable.h"
#include "core/pipeline/avatar_file_info.h"
#include "core/pipeline/avatar_state.h"
#include "core/pipeline/detail_source.h"
#include "core/pipeline/morphable_preview.h"
#include "core/pipeline/quality.h"
#include "core/pipeline/reconstruct.h"
#include "core/pipeline/session.h"
#include "core/pipeline/session_source.h"
#include "core/pipeline/source_analysis.h"
#include "core/util/error.h"
#include "core/util/logging.h"

namespace avatar {
namespace {

// Driving frames need landmarks only: no matte, no identity embedding.
const face::FaceAnalyzer& SharedAnalyzer(const std::string& data_dir) {
  face::FaceAnalyzerOptions options;
  options.data_dir = data_dir;
  options.matte = false;
  options.embedding = false;
  return face::SharedFaceAnalyzer(options);
}

// Driving frames: the face tracker follows the main face, the morphable model is fitted to
// each frame's landmarks.
class TrackingAnalyzer : public FrameAnalyzer {
 public:
  TrackingAnalyzer(const face::FaceAnalyzer& analyzer, const morphable::MorphableModel& model)
      : tracker_(std::make_unique<face::FaceTracker>(analyzer)),
        fitter_(
            model,
            [this](const cv::Mat& bgr, face::Landmarks* landmarks) {
              const face::TrackedFace tracked = tracker_->Track(bgr, time_);
              time_ += 1.0 / 25.0;
              if (!tracked.found) return false;
              *landmarks = tracked.landmarks;
              return true;
            },
            [this] {
              tracker_->Reset();
              time_ = 0.0;
            }) {}
  FrameMeasurement Measure(const cv::Mat& bgr, RunContext& ctx) override { return fitter_.Measure(bgr, ctx); }
  void Reset() override { fitter_.Reset(); }

 private:
  std::unique_ptr<face::FaceTracker> tracker_;
  double time_ = 0.0;
  MorphableFrameAnalyzer fitter_;
};

std::shared_ptr<const FrameSource> MorphablePreview(const SourceAnalysis& analysis, const std::string& label) {
  auto source = std::make_shared<MorphablePreviewSource>(*analysis.model, analysis.morphable_fit, analysis.texture,
                                                         analysis.overlay, label);
  source->SetWarnings(analysis.warnings);
  return source;
}

// The detail path's options of `mode` as the backend options say (without the fusion net).
DetailOptions DetailOptionsOf(const BackendOptions& options, const std::string& mode) {
  DetailOptions detail;
  detail.mode = mode == "geometric" ? "head" : mode;
  detail.base_expression_every = options.network_expression_every;
  detail.align_depth_to_face = options.align_depth >= 0.0;
  detail.align_depth_reach = std::max(0.0, options.align_depth);
  return detail;
}

// The photo's detail path over a network source, as options.detail and options.fusion say.
std::shared_ptr<const FrameSource> WithPhotoDetail(std::shared_ptr<const FrameSource> network,
                                                   const SourceAnalysis& analysis, const BackendOptions& options) {
  if (options.detail == "off") return network;
  DetailOptions detail = DetailOptionsOf(options, options.detail);
  std::string note;
  detail.fusion = FusionWeightsOf(options, &note);
  auto source = std::make_shared<DetailFrameSource>(std::move(network), analysis, detail);
  if (!note.empty()) {
    std::vector<std::string> warnings = source->Warnings();
    warnings.push_back(note);
    source->SetWarnings(std::move(warnings));
  }
  return source;
}

std::shared_ptr<const FrameSource> NeuralAvatar(SourceAnalysis analysis, const BackendOptions& options,
                                                std::shared_ptr<const Session> session, RunContext& ctx) {
  ctx.Report("reconstruct the neural avatar", 0.7);
  ReconstructionOptions ro;
  ro.quality = options.quality;
  ro.data_dir = options.data_dir;
  Reconstruction r;
  {
    RunContext::ProgressRange range(ctx, 0.7, 1.0);
    r = ReconstructAnalysed(*session, std::move(analysis), ro, ctx);
  }
  auto source = std::make_shared<SessionFrameSource>(std::move(session), std::move(r.avatar), options.random_weights,
                                                     r.analysis.overlay);
  if (r.render) source->SetRenderSettings(*r.render);
  source->SetWarnings(r.analysis.warnings);
  return WithPhotoDetail(std::move(source), r.analysis, options);
}

}  // namespace

std::shared_ptr<const Session> SharedSession(const BackendOptions& options) {
  static std::mutex mutex;
  static std::map<std::string, std::shared_ptr<const Session>> sessions;
  SessionOptions so;
  so.checkpoint = options.checkpoint;
  so.random_weights = options.random_weights && options.checkpoint.empty();
  so.config = options.config;
  so.data_dir = options.data_dir;
  std::string origin;
  const std::string key = ResolveCheckpoint(so, &origin).string() + "|" + origin + "|" + options.config + "|" +
                          options.data_dir;
  std::lock_guard<std::mutex> lock(mutex);
  auto& slot = sessions[key];
  if (!slot) slot = std::make_shared<const Session>(so);
  return slot;
}

std::string FusionWeightsOf(const BackendOptions& options, std::string* note) {
  if (!options.fusion.empty()) return options.fusion;
  if (options.detail != "head" || options.random_weights || options.renderer != "neural") return {};
  const std::filesystem::path bundled = ResourcePath(kBundledFusionFile);
  std::error_code ec;
  if (std::filesystem::is_regular_file(bundled, ec)) return bundled.string();
  if (note != nullptr) {
    std::string looked;
    for (const auto& p : ResourceCandidates(kBundledFusionFile)) looked += (looked.empty() ? "" : ", ") + p.string();
    *note = "The learned finish (the bundled fusion net) is not installed (looked in " + looked +
            "): the frames are the geometric composite, as with --detail geometric; reinstall the package to get it.";
  }
  return {};
}

void BackendOptions::Validate() const {
  AVATAR_CHECK_OPTION(renderer == "neural" || renderer == "morphable")
      << "--renderer must be neural or morphable, got '" << renderer << "'";
  AVATAR_CHECK_OPTION(config == "lite" || config == "paper")
      << "--config must be lite or paper, got '" << config << "'";
  if (!quality.empty()) QualityLevelByName(quality);
  AVATAR_CHECK_OPTION(detail == "head" || detail == "geometric" || detail == "face" || detail == "off")
      << "--detail must be head, geometric, face or off, got '" << detail << "'";
  AVATAR_CHECK_OPTION(fusion.empty() || (detail != "off" && detail != "geometric"))
      << "--fusion finishes the detail path's frames with a learned net: it needs --detail head or face, not "
      << detail;
  AVATAR_CHECK_OPTION(network_expression_every >= 1 && network_expression_every <= 100)
      << "--network-expression-every must be within 1..100, got " << network_expression_every;
  AVATAR_CHECK_OPTION(std::isfinite(align_depth) && align_depth <= 10.0)
      << "--align-depth must be at most 10 (image heights; < 0 = off), got " << align_depth;
}

std::shared_ptr<const FrameSource> CreateFrameSource(const cv::Mat& portrait, const BackendOptions& options,
                                                     RunContext& ctx) {
  options.Validate();
  AVATAR_CHECK_INPUT(!portrait.empty() && portrait.type() == CV_8UC3) << "the portrait must be a BGR8 image";
  // The model first (a bad --checkpoint fails before the slow analysis), then one analysis of the
  // portrait for whichever renderer shows it.
  std::shared_ptr<const Session> session;
  std::string preview_reason;
  if (options.renderer == "morphable" && !options.random_weights) {
    preview_reason = "chosen instead of the neural avatar";
  } else if (options.random_weights || !options.checkpoint.empty()) {
    // A model the user named (or random weights) must load: no silent fallback.
    ctx.Report(options.random_weights ? "build the network (random weights)" : "load the neural model", 0.0);
    session = SharedSession(options);
  } else {
    ctx.Report("load the neural model", 0.0);
    try {
      session = SharedSession(options);
    } catch (const MissingData& e) {
      preview_reason = std::string("neural model unavailable: ") + e.what();
    } catch (const ModelLoad& e) {
      preview_reason = std::string("neural model unavailable: ") + e.what();
    }
    if (!session) {
      AVATAR_LOG(kWarning) << "showing the morphable preview: " << preview_reason;
    }
  }
  ctx.ThrowIfCancelled();
  SourceAnalysis analysis;
  {
    RunContext::ProgressRange range(ctx, 0.1, session ? 0.7 : 1.0);
    analysis = AnalyseSource(portrait, options.data_dir, ctx);
  }
  if (!session) {
    ctx.Report("done", 1.0);
    return MorphablePreview(analysis, std::string(kMorphablePreviewLabel) + " (" + preview_reason + ")");
  }
  return NeuralAvatar(std::move(analysis), options, std::move(session), ctx);
}

PortraitPaths CreatePortraitPaths(const cv::Mat& portrait, const BackendOptions& options, RunContext& ctx) {
  options.Validate();
  AVATAR_CHECK_INPUT(!portrait.empty() && portrait.type() == CV_8UC3) << "the portrait must be a BGR8 image";
  ctx.Report("load the neural model", 0.0);
  SharedSession(options);  // a bad model fails before the slow analysis
  SourceAnalysis analysis;
  {
    RunContext::ProgressRange range(ctx, 0.1, 0.7);
    analysis = AnalyseSource(portrait, options.data_dir, ctx);
  }
  return CreatePortraitPaths(std::move(analysis), options, ctx);
}

PortraitPaths CreatePortraitPaths(SourceAnalysis analysis, const BackendOptions& options, RunContext& ctx) {
  options.Validate();
  std::shared_ptr<const Session> session = SharedSession(options);
  PortraitPaths paths;
  paths.preview = MorphablePreview(analysis, kMorphablePreviewLabel);
  paths.portrait = analysis.portrait;
  const SourceAnalysis kept = analysis;
  BackendOptions plain = options;
  plain.detail = "off";
  paths.network = NeuralAvatar(std::move(analysis), plain, std::move(session), ctx);
  const DetailOptions face = DetailOptionsOf(options, "face"), head = DetailOptionsOf(options, "head");
  paths.face = std::make_shared<DetailFrameSource>(paths.network, kept, face);
  const auto bake_start = std::chrono::steady_clock::now();
  paths.detail = std::make_shared<DetailFrameSource>(paths.network, kept, head);
  paths.bake_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - bake_start).count();
  DetailOptions learned = head;
  learned.fusion = FusionWeightsOf(options);
  if (!learned.fusion.empty()) paths.learned = std::make_shared<DetailFrameSource>(paths.network, kept, learned);
  return paths;
}

std::shared_ptr<const FrameSource> SavedAvatarSource(std::shared_ptr<const Session> session, const Avatar& avatar,
                                                     const BackendOptions& options, const RenderSettings* settings) {
  options.Validate();
  AVATAR_CHECK_INPUT(session != nullptr && avatar.valid()) << "SavedAvatarSource needs a session and a loaded avatar";
  const bool detail = options.detail != "off" && avatar.HasPortraitAnalysis();
  SourceAnalysis analysis;
  if (detail) {
    const AvatarPortrait& kept = *avatar.state()->portrait;
    analysis = AnalysisFromFit(kept.portrait, kept.fit, options.data_dir);
  }
  auto network = std::make_shared<SessionFrameSource>(std::move(session), avatar, options.random_weights,
                                                      analysis.overlay);
  if (settings != nullptr) network->SetRenderSettings(*settings);
  if (detail) return WithPhotoDetail(std::move(network), analysis, options);
  if (options.detail != "off") {
    network->SetWarnings({"This avatar file does not keep its portrait's analysis (it was saved before 2026-12-05), so "
                          "it renders without the photo's detail: reconstruct the portrait again to get it."});
  }
  return network;
}

std::shared_ptr<const FrameSource> OpenAvatarSource(const std::string& input, const BackendOptions& options,
                                                    RunContext& ctx) {
  options.Validate();
  std::string ext = std::filesystem::path(input).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext == ".avatar") {
    ctx.Report("load avatar", 0.0, input);
    SessionOptions so;
    so.checkpoint = options.checkpoint;
    so.data_dir = options.data_dir;
    so.random_weights = options.random_weights;
    // The avatar names its random weights (RandomModelId): rebuild exactly those.
    if (so.random_weights && so.checkpoint.empty())
      ParseRandomModelId(ReadAvatarFileInfo(input).model_id, &so.config, &so.seed);
    const auto session = std::make_shared<const Session>(so);
    return SavedAvatarSource(session, session->LoadAvatar(input), options);
  }
  ctx.Report("load portrait", 0.0, input);
  const cv::Mat portrait = LoadImageBgr(input);
  try {
    return CreateFrameSource(portrait, options, ctx);
  } catch (const InvalidInput& e) {
    throw InvalidInput("portrait '" + input + "': " + e.what());
  }
}

FrameAnalyzerFactory DrivingAnalyzers(const BackendOptions& options) {
  const std::string data_dir = options.data_dir;
  return [data_dir](RunContext& ctx) -> std::unique_ptr<FrameAnalyzer> {
    ctx.Report("load face models", 0.0);
    const DataPaths paths = DataPaths::Resolve(data_dir);
    const morphable::MorphableModel& model = morphable::LoadDefaultModel(paths);
    return std::make_unique<TrackingAnalyzer>(SharedAnalyzer(data_dir), model);
  };
}

std::string BackendStatement(const BackendOptions& options) {
  if (options.random_weights) return "The neural network runs with RANDOM weights: the frames are not a result.";
  if (options.renderer == "morphable") {
    return "Renderer: the morphable-model preview (textured face mask; no hair or ears), as chosen.";
  }
  SessionOptions so;
  so.checkpoint = options.checkpoint;
  so.data_dir = options.data_dir;
  try {
    std::string origin;
    const std::filesystem::path path = ResolveCheckpoint(so, &origin);
    return "Renderer: the " + std::string(origin == "bundled" ? "bundled " : "") + "neural avatar model '" +
           path.filename().string() + "'.";
  } catch (const MissingData& e) {
    return std::string("Renderer: the morphable-model preview, because no neural model was found: ") + e.what();
  }
}

}  // namespace avatar
