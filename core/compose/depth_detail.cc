#include "core/compose/depth_detail.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "core/morphable/rasterizer.h"
#include "core/render/view_pose.h"
#include "core/util/error.h"
#include "core/util/push_pull.h"

namespace avatar::compose {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// A depth map (CV_32FC1, non-finite = empty) as its values (0 where empty) and the CV_8UC1 mask
// of its finite pixels (255).
void SplitKnown(const cv::Mat& depth, cv::Mat* values, cv::Mat* known) {
  AVATAR_CHECK_INPUT(!depth.empty() && depth.type() == CV_32FC1) << "a depth map must be CV_32FC1";
  *values = cv::Mat(depth.size(), CV_32FC1);
  *known = cv::Mat(depth.size(), CV_8UC1);
  for (int y = 0; y < depth.rows; ++y) {
    for (int x = 0; x < depth.cols; ++x) {
      const float d = depth.at<float>(y, x);
      const bool ok = std::isfinite(d);
      known->at<uchar>(y, x) = ok ? 255 : 0;
      values->at<float>(y, x) = ok ? d : 0.0f;
    }
  }
}

// Bilinear sample of a finite-or-inf map at continuous pixel position (x, y) (pixel centres at
// i + 0.5); +inf when any of the four neighbours is not finite or the point is outside.
float SampleDepth(const cv::Mat& depth, double x, double y) {
  const double fx = x - 0.5, fy = y - 0.5;
  const int x0 = static_cast<int>(std::floor(fx)), y0 = static_cast<int>(std::floor(fy));
  if (x0 < 0 || y0 < 0 || x0 + 1 >= depth.cols || y0 + 1 >= depth.rows) {
    const int xi = std::clamp(static_cast<int>(std::floor(x)), 0, depth.cols - 1);
    const int yi = std::clamp(static_cast<int>(std::floor(y)), 0, depth.rows - 1);
    if (x < 0 || y < 0 || x >= depth.cols || y >= depth.rows) return kInf;
    return depth.at<float>(yi, xi);
  }
  const double ax = fx - x0, ay = fy - y0;
  const float a = depth.at<float>(y0, x0), b = depth.at<float>(y0, x0 + 1);
  const float c = depth.at<float>(y0 + 1, x0), d = depth.at<float>(y0 + 1, x0 + 1);
  if (!std::isfinite(a) || !std::isfinite(b) || !std::isfinite(c) || !std::isfinite(d)) return kInf;
  return static_cast<float>((1 - ay) * ((1 - ax) * a + ax * b) + ay * ((1 - ax) * c + ax * d));
}

}  // namespace

void DepthDetailOptions::Validate() const {
  AVATAR_CHECK_OPTION(std::isfinite(depth_tolerance) && depth_tolerance > 0.0 && depth_tolerance < 1.0)
      << "the depth-detail tolerance must be in (0, 1), got " << depth_tolerance;
  AVATAR_CHECK_OPTION(min_alpha >= 0 && min_alpha <= 255) << "the depth-detail alpha threshold must be 0..255";
  AVATAR_CHECK_OPTION(std::isfinite(min_matte) && min_matte >= 0.0f && min_matte <= 1.0f)
      << "the depth-detail matte threshold must be in [0, 1], got " << min_matte;
  AVATAR_CHECK_OPTION(std::isfinite(outline_matte) && outline_matte > 0.0f && outline_matte <= min_matte)
      << "the outline's matte threshold must be in (0, min_matte], got " << outline_matte;
  AVATAR_CHECK_OPTION(std::isfinite(depth_smoothing) && depth_smoothing >= 0.0 && depth_smoothing <= 0.25)
      << "the depth smoothing must be in [0, 0.25], got " << depth_smoothing;
  AVATAR_CHECK_OPTION(std::isfinite(feather) && feather >= 0.0 && feather <= 0.25)
      << "the depth-detail feather must be in [0, 0.25], got " << feather;
  AVATAR_CHECK_OPTION(std::isfinite(carve_matte) && carve_matte <= 1.0f)
      << "the carve threshold must be at most 1 (< 0 = off), got " << carve_matte;
}

cv::Mat SmoothDepth(const cv::Mat& depth, double smoothing) {
  cv::Mat value, known8, known;
  SplitKnown(depth, &value, &known8);
  known8.convertTo(known, CV_32FC1, 1.0 / 255.0);
  const double sigma = smoothing * depth.rows;
  if (sigma >= 0.3) {
    // Normalised convolution: the finite values spread over the gaps between them.
    cv::GaussianBlur(known, known, cv::Size(0, 0), sigma);
    cv::GaussianBlur(value, value, cv::Size(0, 0), sigma);
  }
  cv::Mat out(depth.size(), CV_32FC1);
  for (int y = 0; y < depth.rows; ++y) {
    for (int x = 0; x < depth.cols; ++x) {
      const float k = known.at<float>(y, x);
      out.at<float>(y, x) = k > 1e-3f ? value.at<float>(y, x) / k : kInf;
    }
  }
  return out;
}

cv::Mat FillGaps(const cv::Mat& depth) {
  cv::Mat values, known;
  SplitKnown(depth, &values, &known);
  if (cv::countNonZero(known) == 0) return cv::Mat(depth.size(), CV_32FC1, cv::Scalar(kInf));
  cv::Mat filled = PushPullFill(values, known);
  values.copyTo(filled, known);  // the known values exactly
  return filled;
}

DepthDetail::DepthDetail(cv::Mat photo, cv::Mat matte, ViewDepth source, const DepthDetailOptions& options)
    : photo_(std::move(photo)), matte_(std::move(matte)), source_(std::move(source)), options_(options) {
  options_.Validate();
  AVATAR_CHECK_INPUT(!photo_.empty() && photo_.type() == CV_8UC3) << "the detail photo must be an 8-bit BGR image";
  if (matte_.empty()) matte_ = cv::Mat(photo_.size(), CV_32FC1, cv::Scalar(1.0f));
  AVATAR_CHECK_INPUT(matte_.type() == CV_32FC1 && matte_.size() == photo_.size())
      << "the detail matte must be CV_32FC1 of the photo's size";
  AVATAR_CHECK_INPUT(!source_.depth.empty() && source_.depth.type() == CV_32FC1)
      << "the source-view depth must be a CV_32FC1 map";
  morphable::PinholeCamera::FromLabel(source_.camera);  // throws for a bad camera
  source_.depth = SmoothDepth(source_.depth, options_.depth_smoothing);
  AVATAR_CHECK_INPUT(cv::countNonZero(source_.depth < kInf) > 0) << "the source-view depth is empty (no opaque pixel)";
  filled_ = FillGaps(source_.depth);
}

cv::Mat DepthDetail::SplatPerson(const morphable::PinholeCamera& camera, cv::Size size) const {
  // The person on a grid of the source view half as fine as the target, one point per grid
  // pixel; each point covers two target pixels around it, so that a turned surface shows no
  // pinholes. The splat decides opacity and depth only: the outline is the matte's, tested per
  // target pixel in Warp.
  const int side = std::max(1, (std::max(size.width, size.height) + 1) / 2);
  const cv::Size grid(
      side, std::max(1, static_cast<int>(std::lround(static_cast<double>(side) * photo_.rows / photo_.cols))));
  cv::Mat depth, matte;
  cv::resize(filled_, depth, grid, 0, 0, cv::INTER_LINEAR);
  cv::resize(matte_, matte, grid, 0, 0, grid.width < photo_.cols ? cv::INTER_AREA : cv::INTER_LINEAR);
  const morphable::PinholeCamera scam = morphable::PinholeCamera::FromLabel(source_.camera);
  const PixelRays rays(scam);
  cv::Mat z(size, CV_32FC1, cv::Scalar(kInf));
  constexpr int kHalf = 2;
  for (int y = 0; y < grid.height; ++y) {
    for (int x = 0; x < grid.width; ++x) {
      if (matte.at<float>(y, x) < options_.outline_matte) continue;
      const float d = depth.at<float>(y, x);
      if (!std::isfinite(d) || d <= 0.0f) continue;
      const cv::Vec3d world = rays.Point(x, y, grid, d);
      const cv::Vec3d p = camera.ToCamera(world);
      if (!(p[2] > 1e-6)) continue;
      const cv::Point2d px = camera.ToPixel(p, size);
      if (!(std::abs(px.x) < 1e6 && std::abs(px.y) < 1e6)) continue;
      const int cx = static_cast<int>(std::floor(px.x)), cy = static_cast<int>(std::floor(px.y));
      const float dist = static_cast<float>(cv::norm(world - camera.centre));
      for (int yy = std::max(0, cy - kHalf); yy <= std::min(size.height - 1, cy + kHalf); ++yy) {
        for (int xx = std::max(0, cx - kHalf); xx <= std::min(size.width - 1, cx + kHalf); ++xx) {
          float& cell = z.at<float>(yy, xx);
          cell = std::min(cell, dist);
        }
      }
    }
  }
  return z;
}

FaceWarp DepthDetail::Warp(const ViewDepth& target, const cv::Mat& alpha) const {
  AVATAR_CHECK_INPUT(!target.depth.empty() && target.depth.type() == CV_32FC1) << "the target depth must be CV_32FC1";
  AVATAR_CHECK_INPUT(alpha.type() == CV_8UC1 && alpha.size() == target.depth.size())
      << "the target alpha must be CV_8UC1 of the depth's size";
  const cv::Size size = target.depth.size();
  const morphable::PinholeCamera tcam = morphable::PinholeCamera::FromLabel(target.camera);
  const morphable::PinholeCamera scam = morphable::PinholeCamera::FromLabel(source_.camera);
  // Opaque: where the network is, or where the photo's person lands (extend_to_matte).
  cv::Mat opaque = alpha >= options_.min_alpha;
  cv::Mat depth;
  if (options_.extend_to_matte) {
    const cv::Mat splat = SplatPerson(tcam, size);
    cv::Mat combined = target.depth.clone();
    for (int y = 0; y < size.height; ++y) {
      for (int x = 0; x < size.width; ++x) {
        if (opaque.at<uchar>(y, x) != 0) continue;
        const float s = splat.at<float>(y, x);
        combined.at<float>(y, x) = s;
        if (std::isfinite(s)) opaque.at<uchar>(y, x) = 255;
      }
    }
    depth = SmoothDepth(combined, options_.depth_smoothing);
  } else {
    depth = SmoothDepth(target.depth, options_.depth_smoothing);
  }
  const cv::Mat& seen_depth = options_.extend_to_matte ? filled_ : source_.depth;
  const PixelRays rays(tcam);
  const double tolerance = options_.depth_tolerance * render::kCameraRadius;
  const double sx_scale = static_cast<double>(source_.depth.cols) / photo_.cols;
  const double sy_scale = static_cast<double>(source_.depth.rows) / photo_.rows;

  cv::Mat map_x(size, CV_32FC1, cv::Scalar(-1.0f)), map_y(size, CV_32FC1, cv::Scalar(-1.0f));
  cv::Mat coverage(size, CV_32FC1, cv::Scalar(1.0f));
  FaceWarp out;
  out.valid = cv::Mat::zeros(size, CV_8UC1);
  out.face = cv::Mat::zeros(size, CV_8UC1);
  cv::Mat carved = cv::Mat::zeros(size, CV_8UC1);
  // Rows are independent: split over OpenCV's threads.
  cv::parallel_for_(cv::Range(0, size.height), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      for (int x = 0; x < size.width; ++x) {
        if (opaque.at<uchar>(y, x) == 0) continue;
        out.face.at<uchar>(y, x) = 255;
        const float t = depth.at<float>(y, x);
        if (!std::isfinite(t) || t <= 0.0f) continue;
        const cv::Vec3d world = rays.Point(x, y, size, t);
        const cv::Vec3d p = scam.ToCamera(world);
        if (!(p[2] > 1e-6)) continue;
        const cv::Point2d px = scam.ToPixel(p, photo_.size());
        const int ix = static_cast<int>(std::floor(px.x)), iy = static_cast<int>(std::floor(px.y));
        if (ix < 0 || iy < 0 || ix >= photo_.cols || iy >= photo_.rows) continue;
        const bool network = alpha.at<uchar>(y, x) >= options_.min_alpha;
        if (network && matte_.at<float>(iy, ix) < options_.carve_matte) {
          carved.at<uchar>(y, x) = 255;  // the photo saw empty space through this point
          continue;
        }
        if (!network) coverage.at<float>(y, x) = SampleDepth(matte_, px.x, px.y);
        const float seen = SampleDepth(seen_depth, px.x * sx_scale, px.y * sy_scale);
        if (!std::isfinite(seen) || cv::norm(world - scam.centre) > seen + tolerance) continue;            // hidden
        if (matte_.at<float>(iy, ix) < (network ? options_.min_matte : options_.outline_matte)) continue;  // background
        map_x.at<float>(y, x) = static_cast<float>(px.x);
        map_y.at<float>(y, x) = static_cast<float>(px.y);
        out.valid.at<uchar>(y, x) = 255;
      }
    }
  });
  // A pixel the photo's person alone made opaque is the person only where the photo shows it
  // (the splat's footprint reaches a pixel beyond the matte).
  if (options_.extend_to_matte) out.face.setTo(0, (alpha < options_.min_alpha) & (out.valid == 0));
  // Beyond the opaque region lies nothing to blend with: the person's outline stays the photo's.
  const cv::Mat open = out.face == 0;
  FaceWarp warp = WarpFromMaps(photo_, map_x, map_y, out.valid, out.face, options_.feather, open);
  // The photo's soft outline where nothing of the network lies beneath.
  cv::min(coverage, 1.0f, coverage);
  cv::max(coverage, 0.0f, coverage);
  warp.weight = warp.weight.mul(coverage);
  warp.carved = std::move(carved);
  return warp;
}

cv::Mat MeshRayDepth(const morphable::CameraLabel& camera, const std::vector<cv::Point3f>& world,
                     const std::vector<cv::Vec3i>& triangles, cv::Size size) {
  AVATAR_CHECK_INPUT(size.width > 0 && size.height > 0) << "mesh depth: empty image size";
  const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(camera);
  std::vector<morphable::ScreenVertex> screen(world.size());
  for (size_t i = 0; i < world.size(); ++i) {
    const cv::Vec3d c = cam.ToCamera(cv::Vec3d(world[i].x, world[i].y, world[i].z));
    const cv::Point2d px = cam.ToPixel(c, size);
    screen[i] = {px.x, px.y, c[2]};
  }
  cv::Mat depth = morphable::Rasterize(screen, triangles, size).depth;  // camera z
  // z -> distance along the ray: the ray's length per unit of z.
  const cv::Matx33d k_inv = cam.k_normalised.inv();
  for (int y = 0; y < size.height; ++y) {
    float* row = depth.ptr<float>(y);
    for (int x = 0; x < size.width; ++x) {
      if (!std::isfinite(row[x])) continue;
      const cv::Vec3d d = k_inv * cv::Vec3d((x + 0.5) / size.width, (y + 0.5) / size.height, 1.0);
      row[x] = static_cast<float>(row[x] * cv::norm(d) / d[2]);
    }
  }
  return depth;
}

double FaceDepthOffset(const cv::Mat& network_depth, const cv::Mat& alpha, const cv::Mat& mesh_depth, int min_alpha,
                       int min_pixels) {
  AVATAR_CHECK_INPUT(network_depth.type() == CV_32FC1 && mesh_depth.type() == CV_32FC1 && alpha.type() == CV_8UC1 &&
                     network_depth.size() == mesh_depth.size() && alpha.size() == mesh_depth.size())
      << "face depth offset: the network's depth, its opacity and the mesh's depth must be maps of one size";
  std::vector<float> gaps;
  for (int y = 0; y < mesh_depth.rows; ++y) {
    const float* n = network_depth.ptr<float>(y);
    const float* m = mesh_depth.ptr<float>(y);
    const uchar* a = alpha.ptr<uchar>(y);
    for (int x = 0; x < mesh_depth.cols; ++x)
      if (a[x] >= min_alpha && std::isfinite(n[x]) && std::isfinite(m[x])) gaps.push_back(m[x] - n[x]);
  }
  if (static_cast<int>(gaps.size()) < std::max(1, min_pixels)) return 0.0;
  auto mid = gaps.begin() + static_cast<std::ptrdiff_t>(gaps.size() / 2);
  std::nth_element(gaps.begin(), mid, gaps.end());
  return *mid;
}

cv::Mat FaceOffsetField(const cv::Mat& face, double offset, double reach) {
  AVATAR_CHECK_INPUT(!face.empty() && face.type() == CV_8UC1) << "face offset field: the face mask must be CV_8UC1";
  if (reach <= 0.0) return cv::Mat(face.size(), CV_32FC1, cv::Scalar(offset));
  if (offset == 0.0 || cv::countNonZero(face) == 0) return cv::Mat::zeros(face.size(), CV_32FC1);
  cv::Mat distance;
  cv::distanceTransform(face == 0, distance, cv::DIST_L2, cv::DIST_MASK_5);  // 0 on the face
  const double scale = 1.0 / (reach * face.rows);
  cv::Mat field;
  cv::multiply(distance, distance, field, scale * scale);
  cv::exp(-field, field);
  return field * offset;
}

}  // namespace avatar::compose
