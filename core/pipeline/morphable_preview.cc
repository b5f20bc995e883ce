#include "core/pipeline/morphable_preview.h"

#include <cmath>
#include <limits>

#include "core/util/error.h"

namespace avatar {
namespace {

constexpr double kDegrees = 180.0 / 3.14159265358979323846;

cv::Matx33d RotX(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {1, 0, 0, 0, c, -s, 0, s, c};
}
cv::Matx33d RotY(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {c, 0, s, 0, 1, 0, -s, 0, c};
}
cv::Matx33d RotZ(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {c, -s, 0, s, c, 0, 0, 0, 1};
}

const morphable::PinholeCamera& FrontalCamera() {
  static const morphable::PinholeCamera camera = morphable::PinholeCamera::FromLabel(morphable::FrontalLabel());
  return camera;
}

}  // namespace

cv::Matx33d HeadRotation(const ViewPose& pose) {
  // World: y up, the face looks towards +z at the frontal camera, image right = +x. A
  // positive standard rotation about y moves the nose to image right, about x moves it
  // down, about z turns the face counter-clockwise: our positive angles are the opposites.
  // Order: yaw first, then pitch about the world x axis, then roll about the viewing axis,
  // which is exactly an orbit camera (azimuth, elevation, roll) around a still head.
  return RotZ(-pose.roll / kDegrees) * RotX(-pose.pitch / kDegrees) * RotY(-pose.yaw / kDegrees);
}

ViewPose PoseFromRotation(const cv::Matx33d& r) {
  // r = Rz(c) Rx(b) Ry(a): r(2,1) = sin b, r(2,0) = -cos b sin a, r(2,2) = cos b cos a,
  // r(0,1) = -sin c cos b, r(1,1) = cos c cos b.
  const double b = std::asin(std::clamp(r(2, 1), -1.0, 1.0));
  const double a = std::atan2(-r(2, 0), r(2, 2));
  const double c = std::atan2(-r(0, 1), r(1, 1));
  ViewPose p;
  p.yaw = -a * kDegrees;
  p.pitch = -b * kDegrees;
  p.roll = -c * kDegrees;
  return p;
}

ViewPose PoseOfFit(const morphable::FitResult& fit) {
  // fit.rotation = R_front * R_head (the head turned in front of the frontal camera).
  return PoseFromRotation(FrontalCamera().world_to_cam.t() * fit.rotation);
}

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

RenderedFrame MorphablePreviewSource::Render(const FrameRequest& request, RunContext& ctx) const {
  ValidateFrameSize(request.width, request.height);
  AVATAR_CHECK_OPTION(std::isfinite(request.view.yaw) && std::isfinite(request.view.pitch) &&
                      std::isfinite(request.view.roll) && std::isfinite(request.view.zoom) &&
                      request.view.zoom >= 0.1 && request.view.zoom <= 10.0)
      << "view pose must be finite with zoom in 0.1..10";
  ctx.ThrowIfCancelled();
  const int k = model_.num_expression();
  morphable::Beta beta = request.expression.coefficients_absolute ? model_.ZeroBeta() : fit_.beta;
  const auto& coefficients = request.expression.coefficients;
  if (!coefficients.empty()) {
    AVATAR_CHECK_INPUT(static_cast<int>(coefficients.size()) == k)
        << "expression has " << coefficients.size() << " coefficients, the morphable model has " << k;
    for (int i = 0; i < k; ++i) beta[i] += coefficients[i];
  }
  std::map<std::string, float> controls;
  for (const auto& [name, value] : request.expression.controls) {
    if (value != 0.0f) controls[name] = value;
  }
  if (!controls.empty()) {
    const morphable::Beta offset = model_.ExpressionFromControls(controls);  // Throws on unknown names.
    for (int i = 0; i < k; ++i) beta[i] += offset[i];
  }
  std::vector<cv::Point3f> vertices = morphable::WorldVertices(model_, fit_, &beta);
  const cv::Matx33d rotation = HeadRotation(request.view);
  for (auto& v : vertices) {
    const cv::Vec3d r = rotation * cv::Vec3d(v.x, v.y, v.z);
    v = cv::Point3f(static_cast<float>(r[0]), static_cast<float>(r[1]), static_cast<float>(r[2]));
  }
  const morphable::PinholeCamera& front = FrontalCamera();
  const morphable::CameraLabel camera = morphable::LabelFromPose(front.world_to_cam, front.centre / request.view.zoom);
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

std::map<std::string, float> ControlsFromCoefficients(const morphable::MorphableModel& model,
                                                      const std::vector<float>& beta) {
  const int k = model.num_expression();
  AVATAR_CHECK_INPUT(static_cast<int>(beta.size()) == k)
      << "expected " << k << " expression coefficients, got " << beta.size();
  const auto& controls = model.controls();
  std::map<std::string, float> out;
  if (controls.empty()) return out;
  const int n = static_cast<int>(controls.size());
  // Least squares in the space whitened by the expression std, so every component counts
  // by how unusual it is; solved with SVD (control directions may be nearly dependent).
  cv::Mat d(k, n, CV_64F), b(k, 1, CV_64F);
  for (int r = 0; r < k; ++r) {
    const double w = 1.0 / std::max(1e-6f, model.expression_std()[r]);
    b.at<double>(r) = beta[r] * w;
    for (int c = 0; c < n; ++c) d.at<double>(r, c) = controls[c].direction[r] * w;
  }
  cv::Mat pseudo_inverse;
  cv::invert(d, pseudo_inverse, cv::DECOMP_SVD);  // Minimum-norm solution when under-determined.
  const cv::Mat x = pseudo_inverse * b;
  for (int c = 0; c < n; ++c) {
    const double v = std::clamp(x.at<double>(c), 0.0, 1.0);
    if (v > 0.0) out[controls[c].name] = static_cast<float>(v);
  }
  return out;
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
