#include "core/morphable/measures.h"

#include <cmath>

#include "core/morphable/topology.h"
#include "core/util/error.h"

namespace avatar::morphable {

ExpressionMeasures MeasureShape(const std::vector<cv::Point3f>& p) {
  AVATAR_CHECK_INPUT(p.size() == static_cast<size_t>(kVertexCount))
      << "expression measures need " << kVertexCount << " points, got " << p.size();
  auto d = [&](int a, int b) { return static_cast<double>(cv::norm(p[a] - p[b])); };
  const cv::Point3f right_eye = (p[33] + p[133]) * 0.5f;
  const cv::Point3f left_eye = (p[263] + p[362]) * 0.5f;
  const double iod = cv::norm(right_eye - left_eye);
  AVATAR_CHECK_INPUT(iod > 1e-9) << "expression measures: degenerate shape (the eyes coincide)";
  ExpressionMeasures m;
  m.lip_gap = d(13, 14) / iod;
  m.mouth_width = d(61, 291) / iod;
  m.corner_lift = ((p[61].y + p[291].y) - (p[13].y + p[14].y)) * 0.5 / iod;
  m.brow_height = ((p[105].y - p[159].y) + (p[334].y - p[386].y)) * 0.5 / iod;
  m.brow_inner_gap = d(107, 336) / iod;
  m.eye_open_right = d(159, 145) / iod;
  m.eye_open_left = d(386, 374) / iod;
  m.lip_protrusion = ((p[0].z + p[17].z) - (p[61].z + p[291].z)) * 0.5 / iod;
  return m;
}

ExpressionMeasures MeasureLandmarks(const face::Landmarks& landmarks) {
  std::vector<cv::Point3f> flipped;
  flipped.reserve(landmarks.points.size());
  for (const auto& q : landmarks.points) flipped.emplace_back(q.x, -q.y, -q.z);
  return MeasureShape(flipped);
}

}  // namespace avatar::morphable
