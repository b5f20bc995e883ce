#include "core/pipeline/morphable_preview.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <type_traits>

#include "core/util/error.h"

namespace avatar {

// CameraLabel25 and morphable::CameraLabel are the same 25 floats.
static_assert(std::is_same_v<CameraLabel25, morphable::CameraLabel>);

ViewPose PoseOfFit(const morphable::FitResult& fit) { return render::PoseOfCamera(fit.camera); }

MorphablePreviewSource::MorphablePreviewSource(const morphable::MorphableModel& model, morphable::FitResult fit,
                                               morphable::Texture texture, SourceOverlay overlay, std::string label)
    : model_(model),
      fit_(std::move(fit)),
      texture_(std::move(texture)),
      overlay_(std::move(overlay)),
      label_(std::move(label)) {
  AVATAR_CHECK_INPUT(static_cast<int>(fit_.beta.size()) == model_.num_expression() &&
                     static_cast<int>(fit_.alpha.size()) == model_.num_identity())
      << "the fit does not belong to this morphable model";
  source_pose_ = PoseOfFit(fit_);
}

std::string MorphablePreviewSource::Label() const { return label_; }

std::vector<std::string> MorphablePreviewSource::ExpressionControls() const {
  std::vector<std::string> names;
  for (const auto& c : model_.controls()) names.push_back(c.name);
  return names;
}

int MorphablePreviewSource::CoefficientCount() const { return model_.num_expression(); }

morphable::Beta MorphablePreviewSource::Coefficients(const FrameExpression& expression) const {
  return ExpressionBeta(model_, fit_.beta, expression);
}

RenderedFrame MorphablePreviewSource::Render(const FrameRequest& request, RunContext& ctx) const {
  ValidateFrameSize(request.width, request.height);
  ctx.ThrowIfCancelled();
  const morphable::CameraLabel camera = CameraForView(request.view, fit_.camera);  // Throws on a bad pose.
  const morphable::Beta beta = Coefficients(request.expression);  // Throws on unknown names, wrong counts.
  const std::vector<cv::Point3f> vertices = morphable::WorldVertices(model_, fit_, &beta);
  morphable::RenderOptions options;
  options.supersample = 2;  // Antialiased edges: partial opacity at the head's outline.
  ctx.ThrowIfCancelled();
  const cv::Size size(request.width, request.height);
  const morphable::RenderResult r = morphable::RenderMesh(vertices, model_.topology(), texture_, camera, size, options);

  RenderedFrame frame;
  r.image.convertTo(frame.bgr, CV_8UC3, 255.0);
  r.mask.convertTo(frame.alpha, CV_8UC1, 255.0);
  frame.depth = r.depth.clone();
  frame.depth.setTo(std::numeric_limits<float>::infinity(), r.depth <= 0.0f);
  const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(camera);
  frame.vertices.reserve(vertices.size());
  for (const auto& v : vertices) {
    const cv::Point2d px = cam.ToPixel(cam.ToCamera(cv::Vec3d(v.x, v.y, v.z)), size);
    frame.vertices.emplace_back(static_cast<float>(px.x), static_cast<float>(px.y));
  }
  frame.landmarks = frame.vertices;
  frame.triangles = model_.topology().triangles;
  return frame;
}

MorphableFrameAnalyzer::MorphableFrameAnalyzer(const morphable::MorphableModel& model, LandmarkFn landmarks_of,
                                               std::function<void()> reset)
    : model_(model), landmarks_of_(std::move(landmarks_of)), reset_(std::move(reset)) {}

FrameMeasurement MorphableFrameAnalyzer::Measure(const cv::Mat& bgr, RunContext& ctx) {
  ctx.ThrowIfCancelled();
  FrameMeasurement m;
  face::Landmarks landmarks;
  if (!landmarks_of_(bgr, &landmarks)) return m;
  morphable::FitOptions options;
  options.iterations = 15;  // Per video frame; the portrait fit uses the default.
  try {
    const morphable::FitResult fit = morphable::Fit(model_, landmarks, bgr.size(), options);
    m.face_found = true;
    m.pose = PoseOfFit(fit);
    m.coefficients = fit.beta;
  } catch (const InvalidInput&) {
    m.face_found = false;  // Degenerate landmarks (a blurred or half-visible face): hold the last frame.
  }
  return m;
}

}  // namespace avatar
