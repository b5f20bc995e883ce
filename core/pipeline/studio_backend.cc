#include "core/pipeline/studio_backend.h"

#include <map>
#include <mutex>

#include <opencv2/imgproc.hpp>

#include "core/face/face_analyzer.h"
#include "core/io/data_paths.h"
#include "core/morphable/morphable.h"
#include "core/pipeline/morphable_preview.h"
#include "core/pipeline/session.h"
#include "core/pipeline/session_source.h"
#include "core/util/error.h"
#include "core/util/logging.h"

namespace avatar {
namespace {

// The preview textures the unmatted crop and needs no identity: skip both networks.
const face::FaceAnalyzer& SharedAnalyzer(const std::string& data_dir) {
  face::FaceAnalyzerOptions options;
  options.data_dir = data_dir;
  options.matte = false;
  options.embedding = false;
  return face::SharedFaceAnalyzer(options);
}

cv::Point2f ToImage(const cv::Matx23d& crop_from_image, const cv::Point2f& p) {
  cv::Mat inverse;
  cv::invertAffineTransform(cv::Mat(crop_from_image), inverse);
  const cv::Matx23d m(inverse);
  return {static_cast<float>(m(0, 0) * p.x + m(0, 1) * p.y + m(0, 2)),
          static_cast<float>(m(1, 0) * p.x + m(1, 1) * p.y + m(1, 2))};
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

// One random-weight session per configuration and data folder (building it is the slow part).
std::shared_ptr<const Session> SharedRandomSession(const BackendOptions& options) {
  static std::mutex mutex;
  static std::map<std::string, std::shared_ptr<const Session>> sessions;
  std::lock_guard<std::mutex> lock(mutex);
  auto& slot = sessions[options.preset + "|" + options.data_dir];
  if (!slot) {
    SessionOptions so;
    so.random_weights = true;  // Explicit opt-in by the user; every frame is labelled.
    so.config = options.preset;
    so.data_dir = options.data_dir;
    slot = std::make_shared<const Session>(so);
  }
  return slot;
}

}  // namespace

void BackendOptions::Validate() const {
  AVATAR_CHECK_OPTION(preset == "lite" || preset == "paper")
      << "--preset must be lite or paper, got '" << preset << "'";
}

std::shared_ptr<const FrameSource> CreateFrameSource(const cv::Mat& portrait, const BackendOptions& options,
                                                     RunContext& ctx) {
  options.Validate();
  AVATAR_CHECK_INPUT(!portrait.empty() && portrait.type() == CV_8UC3) << "the portrait must be a BGR8 image";
  if (options.random_weights) {
    ctx.Report("build the network (random weights)", 0.0);
    std::shared_ptr<const Session> session = SharedRandomSession(options);
    ctx.ThrowIfCancelled();
    Avatar avatar;
    {
      RunContext::ProgressRange range(ctx, 0.1, 1.0);
      avatar = session->Reconstruct(portrait, ctx);
    }
    const morphable::MorphableModel& model = morphable::LoadDefaultModel(DataPaths::Resolve(options.data_dir));
    return std::make_shared<SessionFrameSource>(std::move(session), std::move(avatar), true, &model);
  }
  ctx.Report("load models", 0.0);
  const DataPaths paths = DataPaths::Resolve(options.data_dir);
  const morphable::MorphableModel& model = morphable::LoadDefaultModel(paths);
  const face::FaceAnalyzer& analyzer = SharedAnalyzer(options.data_dir);
  ctx.ThrowIfCancelled();
  face::PortraitReport report;
  face::AlignedPortrait aligned;
  {
    RunContext::ProgressRange range(ctx, 0.1, 0.7);
    aligned = analyzer.AnalyzePortrait(portrait, ctx, &report);
  }
  ctx.Report("fit morphable model", 0.7);
  const morphable::FitResult fit = morphable::Fit(model, aligned.landmarks, aligned.image_unmatted.size());
  ctx.Report("sample texture", 0.9);
  morphable::Texture texture = morphable::SampleTexture(model, fit, aligned.image_unmatted);
  SourceOverlay overlay;
  for (const auto& d : report.faces) overlay.faces.push_back(d.box);
  for (const auto& p : report.image_landmarks.points) overlay.landmarks.emplace_back(p.x, p.y);
  if (overlay.landmarks.empty()) {
    for (const auto& p : aligned.landmarks.points) {
      overlay.landmarks.push_back(ToImage(aligned.crop_from_image, cv::Point2f(p.x, p.y)));
    }
  }
  ctx.Report("done", 1.0);
  return std::make_shared<MorphablePreviewSource>(model, fit, std::move(texture), std::move(overlay));
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
  return "The neural model is not trained yet: the frames show the textured morphable-model face fitted to the "
         "portrait (a preview).";
}

}  // namespace avatar
