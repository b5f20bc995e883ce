#include "core/face/face_geometry.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/util/error.h"

namespace avatar::face {
namespace mesh_index {

const std::vector<int>& RightEye() {
  static const std::vector<int> v = {33, 7, 163, 144, 145, 153, 154, 155, 133, 173, 157, 158, 159, 160, 161, 246};
  return v;
}
const std::vector<int>& LeftEye() {
  static const std::vector<int> v = {263, 249, 390, 373, 374, 380, 381, 382, 362, 398, 384, 385, 386, 387, 388, 466};
  return v;
}
const std::vector<int>& RightBrow() {
  static const std::vector<int> v = {70, 63, 105, 66, 107, 55, 65, 52, 53, 46};
  return v;
}
const std::vector<int>& LeftBrow() {
  static const std::vector<int> v = {300, 293, 334, 296, 336, 285, 295, 282, 283, 276};
  return v;
}
const std::vector<int>& LipsOuter() {
  static const std::vector<int> v = {61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291, 409, 270, 269, 267, 0, 37, 39, 40, 185};
  return v;
}
const std::vector<int>& LipsInner() {
  static const std::vector<int> v = {78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308, 324, 318, 402, 317, 14, 87, 178, 88, 95};
  return v;
}
const std::array<int, 68>& Ibug68() {
  static const std::array<int, 68> v = {
      // jaw, from the image-left ear down the chin to the image-right ear
      127, 234, 93, 132, 58, 172, 136, 150, 152, 379, 365, 397, 288, 361, 323, 454, 356,
      // right brow (image left), then left brow
      70, 63, 105, 66, 107, 336, 296, 334, 293, 300,
      // nose bridge, then nostril base from image left to right
      168, 197, 5, 4, 75, 97, 2, 326, 305,
      // right eye (outer, upper x2, inner, lower x2), left eye (inner, upper x2, outer, lower x2)
      33, 160, 158, 133, 153, 144, 362, 385, 387, 263, 373, 380,
      // outer lips from the right corner, over the top, back along the bottom
      61, 39, 37, 0, 267, 269, 291, 405, 314, 17, 84, 181,
      // inner lips
      78, 82, 13, 312, 308, 317, 14, 87};
  return v;
}

}  // namespace mesh_index

namespace {

cv::Point3d P3(const Landmarks& lm, int i) { return cv::Point3d(lm.points.at(i)); }

cv::Point3d Normalised(const cv::Point3d& v) {
  const double n = cv::norm(v);
  AVATAR_CHECK_INPUT(n > 1e-9 && std::isfinite(n)) << "degenerate landmarks: cannot estimate head pose";
  return v / n;
}

cv::Point2f Rot90(const cv::Point2f& v) { return {-v.y, v.x}; }

}  // namespace

cv::Point2f RegionCentre(const Landmarks& lm, const std::vector<int>& region) {
  cv::Point2d c(0, 0);
  for (int i : region) c += cv::Point2d(lm.points.at(i).x, lm.points.at(i).y);
  return cv::Point2f(c / static_cast<double>(region.size()));
}

HeadPose HeadPoseFromLandmarks(const Landmarks& lm) {
  AVATAR_CHECK_INPUT(lm.points.size() == static_cast<size_t>(kMeshPoints))
      << "head pose needs " << kMeshPoints << " landmarks, got " << lm.points.size();
  // Camera frame: x right, y down, z away from the camera (facemesh depth).
  const cv::Point3d ex = Normalised(P3(lm, mesh_index::kLeftEyeOuter) - P3(lm, mesh_index::kRightEyeOuter));
  const cv::Point3d down = P3(lm, mesh_index::kChin) - P3(lm, mesh_index::kForehead);
  const cv::Point3d ey = Normalised(down - ex * down.dot(ex));
  const cv::Point3d ez = ex.cross(ey);  // into the head; the face looks along -ez
  constexpr double kDeg = 180.0 / M_PI;
  HeadPose pose;
  pose.yaw = static_cast<float>(std::atan2(ez.x, ez.z) * kDeg);
  pose.pitch = static_cast<float>(std::atan2(ez.y, std::hypot(ez.x, ez.z)) * kDeg);
  pose.roll = static_cast<float>(std::atan2(ex.y, ex.x) * kDeg);
  return pose;
}

cv::Matx23d CropTransform(const Landmarks& lm, int size, double scale) {
  AVATAR_CHECK_INPUT(lm.points.size() == static_cast<size_t>(kMeshPoints)) << "crop needs " << kMeshPoints << " landmarks";
  const cv::Point2f eye_img_left = RegionCentre(lm, mesh_index::RightEye());
  const cv::Point2f eye_img_right = RegionCentre(lm, mesh_index::LeftEye());
  const cv::Point2f mouth_a(lm.points[mesh_index::kMouthRight].x, lm.points[mesh_index::kMouthRight].y);
  const cv::Point2f mouth_b(lm.points[mesh_index::kMouthLeft].x, lm.points[mesh_index::kMouthLeft].y);
  const cv::Point2f eye_mid = (eye_img_left + eye_img_right) * 0.5f;
  const cv::Point2f d_eye = eye_img_right - eye_img_left;
  const cv::Point2f d_mouth = (mouth_a + mouth_b) * 0.5f - eye_mid;
  cv::Point2f x = d_eye - Rot90(d_mouth);
  const double xn = cv::norm(x);
  AVATAR_CHECK_INPUT(xn > 1e-6 && std::isfinite(xn)) << "degenerate landmarks: cannot align the face";
  x *= static_cast<float>(std::max(2.0 * cv::norm(d_eye), 1.8 * cv::norm(d_mouth)) * scale / xn);
  const cv::Point2f y = Rot90(x);
  const cv::Point2f c = eye_mid + d_mouth * 0.1f;
  const cv::Point2f src[3] = {c - x - y, c + x - y, c - x + y};
  const cv::Point2f dst[3] = {{0, 0}, {static_cast<float>(size), 0}, {0, static_cast<float>(size)}};
  return cv::Matx23d(cv::getAffineTransform(src, dst));
}

cv::Matx23d SimilarityFromPoints(const std::vector<cv::Point2f>& src, const std::vector<cv::Point2f>& dst) {
  AVATAR_CHECK(src.size() == dst.size() && src.size() >= 2) << "similarity needs matching point lists";
  const double n = static_cast<double>(src.size());
  cv::Point2d ms(0, 0), md(0, 0);
  for (size_t i = 0; i < src.size(); ++i) {
    ms += cv::Point2d(src[i]);
    md += cv::Point2d(dst[i]);
  }
  ms /= n;
  md /= n;
  // In complex form dst - md = z * (src - ms), z = a + ib: least squares z = sum(conj(s) d)/sum|s|^2.
  double a = 0, b = 0, ss = 0;
  for (size_t i = 0; i < src.size(); ++i) {
    const cv::Point2d s = cv::Point2d(src[i]) - ms, d = cv::Point2d(dst[i]) - md;
    a += s.x * d.x + s.y * d.y;
    b += s.x * d.y - s.y * d.x;
    ss += s.x * s.x + s.y * s.y;
  }
  AVATAR_CHECK_INPUT(ss > 1e-12) << "degenerate points: cannot fit a similarity";
  a /= ss;
  b /= ss;
  return cv::Matx23d(a, -b, md.x - (a * ms.x - b * ms.y), b, a, md.y - (b * ms.x + a * ms.y));
}

Landmarks TransformLandmarks(const Landmarks& lm, const cv::Matx23d& m) {
  Landmarks out = lm;
  const double s = std::sqrt(std::abs(m(0, 0) * m(1, 1) - m(0, 1) * m(1, 0)));
  for (auto& p : out.points) {
    const double x = m(0, 0) * p.x + m(0, 1) * p.y + m(0, 2);
    const double y = m(1, 0) * p.x + m(1, 1) * p.y + m(1, 2);
    p = cv::Point3f(static_cast<float>(x), static_cast<float>(y), static_cast<float>(p.z * s));
  }
  return out;
}

cv::Mat EyeMouthMask(const Landmarks& lm, int size, int dilation_px) {
  cv::Mat mask = cv::Mat::zeros(size, size, CV_8UC1);
  if (lm.points.size() != static_cast<size_t>(kMeshPoints)) return mask;
  std::vector<std::vector<cv::Point>> polys;
  for (const auto* region : {&mesh_index::RightEye(), &mesh_index::LeftEye(), &mesh_index::RightBrow(),
                             &mesh_index::LeftBrow(), &mesh_index::LipsOuter()}) {
    std::vector<cv::Point> poly;
    for (int i : *region) poly.emplace_back(cvRound(lm.points[i].x * 16), cvRound(lm.points[i].y * 16));
    polys.push_back(poly);
  }
  cv::fillPoly(mask, polys, cv::Scalar(255), cv::LINE_8, 4);  // 4 fractional bits
  if (dilation_px > 0) {
    const cv::Mat disc = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * dilation_px + 1, 2 * dilation_px + 1));
    cv::dilate(mask, mask, disc);
  }
  return mask;
}

}  // namespace avatar::face
