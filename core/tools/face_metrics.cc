#include "core/tools/face_metrics.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/face/face_analyzer.h"
#include "core/face/head_pose_net.h"
#include "core/io/data_paths.h"
#include "core/morphable/fitter.h"
#include "core/morphable/morphable_model.h"
#include "core/util/error.h"

namespace avatar::face {

void FaceMetricsOptions::Validate() const {
  AVATAR_CHECK_OPTION(analysis_size >= 64 && analysis_size <= 2048)
      << "face metrics: analysis_size must be within 64..2048, got " << analysis_size;
  AVATAR_CHECK_OPTION(min_score > 0.0f && min_score < 1.0f)
      << "face metrics: min_score must be within (0,1), got " << min_score;
  AVATAR_CHECK_OPTION(min_mesh_confidence >= 0.0f && min_mesh_confidence <= 1.0f)
      << "face metrics: min_mesh_confidence must be within [0,1], got " << min_mesh_confidence;
  AVATAR_CHECK_OPTION(fit_iterations >= 1 && fit_iterations <= 500)
      << "face metrics: fit_iterations must be within 1..500, got " << fit_iterations;
}

struct FaceMetrics::Impl {
  const FaceAnalyzer* analyzer = nullptr;
  std::unique_ptr<HeadPoseNet> pose;
  const morphable::MorphableModel* model = nullptr;
};

FaceMetrics::FaceMetrics(const FaceMetricsOptions& options) : options_(options), impl_(std::make_unique<Impl>()) {
  options_.Validate();
  FaceAnalyzerOptions ao;
  ao.data_dir = options_.data_dir;
  ao.min_score = options_.min_score;
  ao.tile_large_images = false;
  ao.matte = false;
  ao.embedding = true;
  ao.min_mesh_confidence = options_.min_mesh_confidence;
  impl_->analyzer = &SharedFaceAnalyzer(ao);
  impl_->pose = std::make_unique<HeadPoseNet>(options_.data_dir);
  if (options_.expression) impl_->model = &morphable::LoadDefaultModel(DataPaths::Resolve(options_.data_dir));
}

FaceMetrics::~FaceMetrics() = default;

namespace {

// Any supported image -> CV_8UC3 BGR; empty Mat for unsupported input.
cv::Mat ToBgr8(const cv::Mat& image) {
  cv::Mat out;
  if (image.type() == CV_8UC3) {
    out = image;
  } else if (image.type() == CV_8UC1) {
    cv::cvtColor(image, out, cv::COLOR_GRAY2BGR);
  } else if (image.type() == CV_8UC4) {
    cv::cvtColor(image, out, cv::COLOR_BGRA2BGR);
  } else if (image.type() == CV_32FC3) {
    image.convertTo(out, CV_8UC3, 255.0);
  }
  return out;
}

}  // namespace

FaceMeasurement FaceMetrics::Measure(const cv::Mat& image) const {
  FaceMeasurement m;
  if (image.empty()) {
    m.reason = "empty image";
    return m;
  }
  cv::Mat bgr = ToBgr8(image);
  if (bgr.empty()) {
    m.reason = "unsupported image type (expected 8-bit BGR, grey or float BGR)";
    return m;
  }
  const int long_side = std::max(bgr.cols, bgr.rows);
  if (long_side < options_.analysis_size) {
    const double s = static_cast<double>(options_.analysis_size) / long_side;
    cv::Mat up;
    cv::resize(bgr, up, cv::Size(std::max(1, static_cast<int>(std::lround(bgr.cols * s))),
                                 std::max(1, static_cast<int>(std::lround(bgr.rows * s)))),
               0, 0, cv::INTER_CUBIC);
    bgr = up;
  }
  try {
    const std::vector<Detection> faces = impl_->analyzer->Detect(bgr);
    if (faces.empty()) {
      m.reason = "no face found";
      return m;
    }
    const int main = std::max(0, MainFaceIndex(faces, bgr.size()));
    const Detection& face = faces[main];
    m.detection_score = face.score;
    const Landmarks lm = impl_->analyzer->Mesh(bgr, face);
    if (lm.points.size() != static_cast<size_t>(kMeshPoints) || lm.confidence < options_.min_mesh_confidence) {
      m.reason = "no face found (landmark confidence " + std::to_string(lm.confidence) + ")";
      return m;
    }
    m.embedding = impl_->analyzer->Embedding(bgr, lm);
    const double back = static_cast<double>(image.cols) / bgr.cols;  // analysis -> given image pixels
    m.landmarks.reserve(lm.points.size());
    for (const cv::Point3f& q : lm.points) {
      m.landmarks.emplace_back(static_cast<float>(q.x * back), static_cast<float>(q.y * back));
    }
    m.pose = impl_->pose->Estimate(bgr, face.box);
    if (impl_->model != nullptr) {
      morphable::FitOptions fo;
      fo.iterations = options_.fit_iterations;
      m.expression = morphable::Fit(*impl_->model, lm, bgr.size(), fo).beta;
    }
  } catch (const Cancelled&) {
    throw;
  } catch (const InvalidInput& e) {
    // Degenerate landmarks and the like: the image has no usable face.
    m = FaceMeasurement{};
    m.reason = std::string("no usable face: ") + e.what();
    return m;
  }
  m.found = true;
  return m;
}

double MouthOpening(const std::vector<cv::Point2f>& landmarks) {
  AVATAR_CHECK_INPUT(landmarks.size() == static_cast<size_t>(kMeshPoints))
      << "mouth opening needs " << kMeshPoints << " facemesh points, got " << landmarks.size();
  // Facemesh: 13 / 14 the inner upper / lower lip at the centre, 10 the top of the forehead,
  // 152 the chin.
  const double height = cv::norm(landmarks[10] - landmarks[152]);
  AVATAR_CHECK_INPUT(std::isfinite(height) && height > 1e-3) << "mouth opening: degenerate face height";
  return cv::norm(landmarks[13] - landmarks[14]) / height;
}

PairFaceMetrics FaceMetrics::Compare(const FaceMeasurement& render, const FaceMeasurement& reference) const {
  PairFaceMetrics p;
  p.render_face = render.found;
  p.reference_face = reference.found;
  if (!p.valid()) return p;
  p.csim = IdentitySimilarity(render.embedding, reference.embedding);
  p.yaw_diff = std::abs(render.pose.yaw - reference.pose.yaw);
  p.pitch_diff = std::abs(render.pose.pitch - reference.pose.pitch);
  p.roll_diff = std::abs(render.pose.roll - reference.pose.roll);
  p.apd = (p.yaw_diff + p.pitch_diff + p.roll_diff) / 3.0;
  if (!render.expression.empty() && render.expression.size() == reference.expression.size()) {
    double s = 0.0;
    for (size_t k = 0; k < render.expression.size(); ++k) s += std::abs(render.expression[k] - reference.expression[k]);
    p.aed = s / static_cast<double>(render.expression.size());
    p.has_aed = true;
  }
  return p;
}

std::vector<PairFaceMetrics> FaceMetrics::Evaluate(const std::vector<cv::Mat>& renders,
                                                   const std::vector<cv::Mat>& references, RunContext& ctx) const {
  AVATAR_CHECK_INPUT(renders.size() == references.size())
      << "face metrics: " << renders.size() << " renders but " << references.size() << " references";
  std::vector<PairFaceMetrics> out;
  out.reserve(renders.size());
  for (size_t i = 0; i < renders.size(); ++i) {
    ctx.ThrowIfCancelled();
    out.push_back(Compare(Measure(renders[i]), Measure(references[i])));
  }
  return out;
}

FaceMetricsSummary FaceMetrics::Summarise(const std::vector<PairFaceMetrics>& pairs) {
  FaceMetricsSummary s;
  s.pairs = static_cast<int>(pairs.size());
  int with_aed = 0;
  for (const auto& p : pairs) {
    if (!p.render_face) ++s.no_face_render;
    if (!p.reference_face) ++s.no_face_reference;
    if (!p.valid()) continue;
    ++s.valid;
    s.csim += p.csim;
    s.apd += p.apd;
    if (p.has_aed) {
      s.aed += p.aed;
      ++with_aed;
    }
  }
  if (s.valid > 0) {
    s.csim /= s.valid;
    s.apd /= s.valid;
  }
  if (with_aed > 0) {
    s.aed /= with_aed;
    s.has_aed = true;
  }
  return s;
}

}  // namespace avatar::face
