#include "core/compose/face_detail.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "core/face/face_geometry.h"
#include "core/morphable/rasterizer.h"
#include "core/render/view_pose.h"
#include "core/util/error.h"

namespace avatar::compose {
namespace {

// A CV_8UC1 mask as a CV_32FC1 weight: 1 on the mask, its edge softened by a pixel outside.
cv::Mat SoftenedByAPixel(const cv::Mat& mask) {
  cv::Mat weight;
  mask.convertTo(weight, CV_32FC1, 1.0 / 255.0);
  cv::GaussianBlur(weight, weight, cv::Size(3, 3), 0.0);
  weight.setTo(1.0f, mask);
  return weight;
}

// Camera-space points and their screen vertices (pixel position, depth) for `size`.
void Project(const morphable::PinholeCamera& cam, const std::vector<cv::Point3f>& world, cv::Size size,
             std::vector<cv::Vec3d>* camera_points, std::vector<morphable::ScreenVertex>* screen) {
  camera_points->resize(world.size());
  screen->resize(world.size());
  for (size_t i = 0; i < world.size(); ++i) {
    (*camera_points)[i] = cam.ToCamera(cv::Vec3d(world[i].x, world[i].y, world[i].z));
    const cv::Point2d px = cam.ToPixel((*camera_points)[i], size);
    (*screen)[i] = {px.x, px.y, (*camera_points)[i][2]};
  }
}

}  // namespace

void FaceDetailOptions::Validate() const {
  AVATAR_CHECK_OPTION(std::isfinite(depth_tolerance) && depth_tolerance > 0.0 && depth_tolerance < 1.0)
      << "the detail depth tolerance must be in (0, 1), got " << depth_tolerance;
  AVATAR_CHECK_OPTION(std::isfinite(min_matte) && min_matte >= 0.0f && min_matte <= 1.0f)
      << "the detail matte threshold must be in [0, 1], got " << min_matte;
  AVATAR_CHECK_OPTION(std::isfinite(feather) && feather >= 0.0 && feather <= 0.25)
      << "the detail feather must be in [0, 0.25], got " << feather;
  AVATAR_CHECK_OPTION(std::isfinite(eye_mouth_motion) && eye_mouth_motion >= 0.0)
      << "the eye/mouth motion threshold must be a finite number >= 0, got " << eye_mouth_motion;
  AVATAR_CHECK_OPTION(std::isfinite(closed_eye_ratio) && closed_eye_ratio >= 0.0 && closed_eye_ratio < 1.0)
      << "the closed-eye ratio must be in [0, 1), got " << closed_eye_ratio;
  AVATAR_CHECK_OPTION(std::isfinite(mouth_cavity_shade) && mouth_cavity_shade <= 1.0)
      << "the mouth cavity shade must be at most 1 (< 0 = off), got " << mouth_cavity_shade;
  AVATAR_CHECK_OPTION(changed_eye_mouth == "network" || changed_eye_mouth == "mesh")
      << "a changed eye or mouth comes from 'network' or 'mesh', got '" << changed_eye_mouth << "'";
}

double EyeOpenRatio(const std::vector<cv::Point2d>& points, int eye) {
  static const int kLids[2][4] = {{159, 145, 33, 133}, {386, 374, 263, 362}};  // upper, lower, corners
  const int* i = kLids[eye == 0 ? 0 : 1];
  if (points.size() <= 386) return 0.0;
  const double width = cv::norm(points[i[2]] - points[i[3]]);
  if (!(width > 1e-9)) return 0.0;
  return cv::norm(points[i[0]] - points[i[1]]) / width;
}

FaceDetail::FaceDetail(const morphable::MorphableModel& model, morphable::FitResult fit, cv::Mat photo, cv::Mat matte,
                       cv::Mat eye_mouth, const FaceDetailOptions& options,
                       const std::vector<cv::Point3f>& photo_landmarks)
    : model_(model),
      fit_(std::move(fit)),
      photo_(std::move(photo)),
      matte_(std::move(matte)),
      eye_mouth_(std::move(eye_mouth)),
      options_(options) {
  options_.Validate();
  AVATAR_CHECK_INPUT(!photo_.empty() && photo_.type() == CV_8UC3) << "the detail photo must be an 8-bit BGR image";
  AVATAR_CHECK_INPUT(photo_.size() == fit_.image_size)
      << "the detail photo is " << photo_.cols << "x" << photo_.rows << " but the fit refers to "
      << fit_.image_size.width << "x" << fit_.image_size.height;
  if (matte_.empty()) matte_ = cv::Mat(photo_.size(), CV_32FC1, cv::Scalar(1.0f));
  if (eye_mouth_.empty()) eye_mouth_ = cv::Mat::zeros(photo_.size(), CV_8UC1);
  AVATAR_CHECK_INPUT(matte_.type() == CV_32FC1 && matte_.size() == photo_.size())
      << "the detail matte must be CV_32FC1 of the photo's size";
  AVATAR_CHECK_INPUT(eye_mouth_.type() == CV_8UC1 && eye_mouth_.size() == photo_.size())
      << "the detail eye/mouth mask must be CV_8UC1 of the photo's size";
  AVATAR_CHECK_INPUT(static_cast<int>(fit_.beta.size()) == model_.num_expression() &&
                     static_cast<int>(fit_.alpha.size()) == model_.num_identity())
      << "the fit does not belong to this morphable model";
  source_world_ = morphable::WorldVertices(model_, fit_);
  const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(fit_.camera);
  std::vector<cv::Vec3d> camera_points;
  std::vector<morphable::ScreenVertex> screen;
  Project(cam, source_world_, photo_.size(), &camera_points, &screen);
  source_depth_ = morphable::Rasterize(screen, model_.topology().triangles, photo_.size()).depth;
  {
    // The lips of the photo (between the outer and the inner lip line of the fitted mesh) give the
    // colour of the mouth's interior; a neutral dark red when the lips are out of the picture.
    std::vector<cv::Point> outer, inner;
    for (const int v : face::mesh_index::LipsOuter()) outer.emplace_back(cvRound(screen[v].x), cvRound(screen[v].y));
    for (const int v : face::mesh_index::LipsInner()) inner.emplace_back(cvRound(screen[v].x), cvRound(screen[v].y));
    cv::Mat lips = cv::Mat::zeros(photo_.size(), CV_8UC1);
    cv::fillPoly(lips, std::vector<std::vector<cv::Point>>{outer}, cv::Scalar(255));
    cv::fillPoly(lips, std::vector<std::vector<cv::Point>>{inner}, cv::Scalar(0));
    const cv::Scalar lip = cv::countNonZero(lips) > 0 ? cv::mean(photo_, lips) : cv::Scalar(60, 60, 150);
    const double shade = std::max(0.0, options_.mouth_cavity_shade);
    for (int c = 0; c < 3; ++c) cavity_colour_[c] = cv::saturate_cast<uchar>(lip[c] * shade);
  }
  if (photo_landmarks.size() == screen.size()) {
    std::vector<cv::Point2d> points;
    for (const cv::Point3f& p : photo_landmarks) points.emplace_back(p.x, p.y);
    for (int eye = 0; eye < 2; ++eye) eye_closed_[eye] = EyeOpenRatio(points, eye) < options_.closed_eye_ratio;
  }
}

void FaceDetail::SetFillTexture(const morphable::Texture& texture) {
  AVATAR_CHECK_INPUT(texture.uv_image.empty() || texture.uv_image.type() == CV_32FC3)
      << "detail: the fill texture must be CV_32FC3";
  AVATAR_CHECK_INPUT(!texture.uv_image.empty() ||
                     texture.vertex_colors.size() == static_cast<size_t>(model_.topology().uv.size()))
      << "detail: the fill texture has neither a UV image nor a colour per vertex";
  fill_texture_ = texture;
  fill_ = true;
}

FaceWarp FaceDetail::Warp(const morphable::CameraLabel& camera, const morphable::Beta& beta, cv::Size size) const {
  AVATAR_CHECK_INPUT(static_cast<int>(beta.size()) == model_.num_expression())
      << "detail: " << beta.size() << " expression coefficients for a model with " << model_.num_expression();
  AVATAR_CHECK_INPUT(size.width >= 1 && size.height >= 1) << "detail: empty output size";
  for (size_t k = 0; k < beta.size(); ++k)
    AVATAR_CHECK_INPUT(std::isfinite(beta[k])) << "detail: expression coefficient " << k << " is not finite";

  const morphable::PinholeCamera target_cam = morphable::PinholeCamera::FromLabel(camera);
  const morphable::PinholeCamera source_cam = morphable::PinholeCamera::FromLabel(fit_.camera);
  const std::vector<cv::Point3f> target_world = morphable::WorldVertices(model_, fit_, &beta);
  std::vector<cv::Vec3d> target_points;
  std::vector<morphable::ScreenVertex> target_screen;
  Project(target_cam, target_world, size, &target_points, &target_screen);
  const morphable::RasterBuffers raster = morphable::Rasterize(target_screen, model_.topology().triangles, size);
  cv::Mat mouth_opening;
  const cv::Mat changed = ChangedEyeMouth(target_world, target_screen, size, &mouth_opening);
  // The mouth's interior: inside the changed mouth's inner lip line, where the mesh only stretches
  // the photo's closed lips.
  cv::Mat cavity = options_.mouth_cavity_shade >= 0.0 ? mouth_opening : cv::Mat::zeros(size, CV_8UC1);

  const auto& triangles = model_.topology().triangles;
  const double tolerance = options_.depth_tolerance * render::kCameraRadius;
  cv::Mat map_x(size, CV_32FC1, cv::Scalar(-1.0f)), map_y(size, CV_32FC1, cv::Scalar(-1.0f));
  FaceWarp out;
  out.valid = cv::Mat::zeros(size, CV_8UC1);
  out.face = cv::Mat::zeros(size, CV_8UC1);
  cv::Mat eye_mouth = cv::Mat::zeros(size, CV_8UC1);
  cv::Mat fill = fill_ ? cv::Mat::zeros(size, CV_8UC3) : cv::Mat();
  const auto& uv = model_.topology().uv;
  const cv::Mat& uv_image = fill_texture_.uv_image;
  // Rows are independent: split over OpenCV's threads.
  cv::parallel_for_(cv::Range(0, size.height), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      for (int x = 0; x < size.width; ++x) {
        const int t = raster.triangle.at<int>(y, x);
        if (t < 0) continue;
        out.face.at<uchar>(y, x) = 255;
        const cv::Vec3f b = raster.bary.at<cv::Vec3f>(y, x);
        const cv::Vec3i& f = triangles[t];
        if (fill_) {
          // The texture as the morphable preview looks it up (texel centres at (i + 0.5) / size).
          cv::Vec3f colour;
          if (!uv_image.empty()) {
            const cv::Point2f at = b[0] * uv[f[0]] + b[1] * uv[f[1]] + b[2] * uv[f[2]];
            colour = morphable::SampleBilinear<cv::Vec3f>(uv_image, at.x * uv_image.cols - 0.5,
                                                          at.y * uv_image.rows - 0.5);
          } else {
            const auto& vc = fill_texture_.vertex_colors;
            colour = b[0] * vc[f[0]] + b[1] * vc[f[1]] + b[2] * vc[f[2]];
          }
          fill.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(colour[0] * 255.0f),
                                               cv::saturate_cast<uchar>(colour[1] * 255.0f),
                                               cv::saturate_cast<uchar>(colour[2] * 255.0f));
        }
        // The same surface point of the mesh at the source expression, seen by the source camera.
        cv::Vec3d world(0, 0, 0);
        for (int k = 0; k < 3; ++k) {
          const cv::Point3f& v = source_world_[f[k]];
          world += static_cast<double>(b[k]) * cv::Vec3d(v.x, v.y, v.z);
        }
        const cv::Vec3d p = source_cam.ToCamera(world);
        if (!(p[2] > 1e-6)) continue;
        const cv::Point2d px = source_cam.ToPixel(p, photo_.size());
        const int sx = static_cast<int>(std::floor(px.x)), sy = static_cast<int>(std::floor(px.y));
        if (sx < 0 || sy < 0 || sx >= photo_.cols || sy >= photo_.rows) continue;
        eye_mouth.at<uchar>(y, x) = eye_mouth_.at<uchar>(sy, sx) != 0 ? 255 : 0;
        if (p[2] > source_depth_.at<float>(sy, sx) + tolerance) continue;  // hidden in the photo
        if (matte_.at<float>(sy, sx) < options_.min_matte) continue;       // background in the photo
        if (changed.at<uchar>(y, x) != 0) continue;                        // the photo shows another expression here
        map_x.at<float>(y, x) = static_cast<float>(px.x);
        map_y.at<float>(y, x) = static_cast<float>(px.y);
        out.valid.at<uchar>(y, x) = 255;
      }
    }
  });
  FaceWarp warp = WarpFromMaps(photo_, map_x, map_y, out.valid, out.face, options_.feather);
  warp.cavity_bgr = cavity_colour_;
  warp.eye_mouth = std::move(eye_mouth);
  warp.changed = changed;
  warp.cavity = std::move(cavity);
  warp.fill_bgr = std::move(fill);
  return warp;
}

double FaceDetail::EyeMouthMotion(const std::vector<cv::Point3f>& target_world, const std::vector<int>& region) const {
  const cv::Point3f& a = source_world_[face::mesh_index::kRightEyeOuter];
  const cv::Point3f& b = source_world_[face::mesh_index::kLeftEyeOuter];
  const double eyes = std::max(1e-6, cv::norm(a - b));
  double motion = 0.0;
  for (const int v : region) motion = std::max(motion, cv::norm(target_world[v] - source_world_[v]));
  return motion / eyes;
}

cv::Mat FaceDetail::ChangedEyeMouth(const std::vector<cv::Point3f>& target_world,
                                    const std::vector<morphable::ScreenVertex>& target_screen, cv::Size size,
                                    cv::Mat* mouth_opening) const {
  cv::Mat changed = cv::Mat::zeros(size, CV_8UC1);
  if (mouth_opening != nullptr) *mouth_opening = cv::Mat::zeros(size, CV_8UC1);
  std::vector<std::vector<cv::Point>> polys;
  // "mesh": the openings only (inside the lid margin, inside the inner lip line), which the mesh
  // spans with stretched lids and lips; "network": the whole eye (lid margin) and mouth (outer lip
  // line), with a margin.
  const bool openings = options_.changed_eye_mouth == "mesh";
  const std::vector<int>& mouth = openings ? face::mesh_index::LipsInner() : face::mesh_index::LipsOuter();
  std::vector<cv::Point2d> target_points;
  for (const morphable::ScreenVertex& p : target_screen) target_points.emplace_back(p.x, p.y);
  const std::vector<int>* regions[] = {&face::mesh_index::RightEye(), &face::mesh_index::LeftEye(), &mouth};
  for (int r = 0; r < 3; ++r) {
    const std::vector<int>* region = regions[r];
    // A closed eye of the photo cannot show an open one, whatever the fit says.
    const bool opened = r < 2 && eye_closed_[r] && EyeOpenRatio(target_points, r) >= options_.closed_eye_ratio;
    if (!opened && EyeMouthMotion(target_world, *region) <= options_.eye_mouth_motion) continue;
    std::vector<cv::Point> poly;
    bool in_front = true;
    for (const int v : *region) {
      const morphable::ScreenVertex& p = target_screen[v];
      in_front = in_front && p.depth > 1e-6 && std::isfinite(p.x) && std::isfinite(p.y) && std::abs(p.x) < 1e6 &&
                 std::abs(p.y) < 1e6;
      poly.emplace_back(cvRound(p.x * 16), cvRound(p.y * 16));
    }
    if (!in_front) continue;
    if (r == 2 && openings && mouth_opening != nullptr)
      cv::fillPoly(*mouth_opening, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(255), cv::LINE_8, 4);
    polys.push_back(std::move(poly));
  }
  if (polys.empty()) return changed;
  cv::fillPoly(changed, polys, cv::Scalar(255), cv::LINE_8, 4);  // 4 fractional bits
  if (!openings) {
    // A margin around the contour: the photo's lids and lips there moved with the expression too.
    const int margin = std::max(1, static_cast<int>(std::lround(0.015 * size.height)));
    cv::dilate(changed, changed,
               cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * margin + 1, 2 * margin + 1)));
  }
  return changed;
}

FaceWarp WarpFromMaps(const cv::Mat& photo, const cv::Mat& map_x, const cv::Mat& map_y, cv::Mat valid, cv::Mat face,
                      double feather, const cv::Mat& open) {
  AVATAR_CHECK_INPUT(map_x.type() == CV_32FC1 && map_y.type() == CV_32FC1 && map_x.size() == valid.size() &&
                     map_y.size() == valid.size() && valid.type() == CV_8UC1)
      << "detail: the warp maps must be CV_32FC1 of the valid mask's size";
  FaceWarp out;
  // cv::remap addresses pixel centres at integers.
  cv::Mat mx = map_x - 0.5f, my = map_y - 0.5f;
  cv::remap(photo, out.bgr, mx, my, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  out.bgr.setTo(cv::Scalar::all(0), valid == 0);
  out.weight = FeatheredWeight(valid, feather, open);
  out.valid = std::move(valid);
  out.face = std::move(face);
  return out;
}

cv::Mat FeatheredWeight(const cv::Mat& valid, double feather, const cv::Mat& open) {
  AVATAR_CHECK_INPUT(!valid.empty() && valid.type() == CV_8UC1) << "detail: the valid mask must be CV_8UC1";
  AVATAR_CHECK_INPUT(open.empty() || (open.type() == CV_8UC1 && open.size() == valid.size()))
      << "detail: the open mask must be CV_8UC1 of the valid mask's size";
  // Feather inwards: the weight reaches 1 a feather width inside the valid region, so the seam
  // with the frame below is soft and never shows the invalid (black) pixels.
  cv::Mat valid_f, weight;
  valid.convertTo(valid_f, CV_32FC1, 1.0 / 255.0);
  const int radius = static_cast<int>(std::lround(feather * valid.rows));
  if (radius >= 1) {
    cv::Mat eroded, reach;
    if (open.empty()) {
      reach = valid_f;
    } else {
      cv::Mat open_f;
      open.convertTo(open_f, CV_32FC1, 1.0 / 255.0);
      cv::max(valid_f, open_f, reach);  // a new matrix: valid_f stays the mask
    }
    cv::erode(reach, eroded, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * radius + 1, 2 * radius + 1)));
    cv::GaussianBlur(eroded, weight, cv::Size(0, 0), radius / 2.0 + 0.5);
    weight = weight.mul(valid_f);
  } else {
    weight = valid_f;
  }
  cv::min(cv::max(weight, 0.0), 1.0, weight);
  return weight;
}

void ExcludeRegion(FaceWarp* warp, const cv::Mat& region, double feather) {
  if (region.empty() || cv::countNonZero(region) == 0) return;
  AVATAR_CHECK_INPUT(region.type() == CV_8UC1 && region.size() == warp->valid.size())
      << "detail: the excluded region must be CV_8UC1 of the warp's size";
  warp->valid.setTo(0, region);
  warp->bgr.setTo(cv::Scalar::all(0), region);
  // 1 on the region and a feather width around it, fading to 0 another feather width out.
  const int radius = std::max(1, static_cast<int>(std::lround(feather * region.rows)));
  cv::Mat grown, soft;
  cv::dilate(region, grown, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * radius + 1, 2 * radius + 1)));
  grown.convertTo(soft, CV_32FC1, 1.0 / 255.0);
  cv::GaussianBlur(soft, soft, cv::Size(0, 0), radius / 2.0 + 0.5);
  soft.setTo(1.0f, region);
  cv::Mat keep = 1.0 - soft;
  cv::max(keep, 0.0, keep);
  warp->weight = warp->weight.mul(keep);
}

cv::Mat Composite(const cv::Mat& base, const FaceWarp& warp, cv::Mat* alpha) {
  AVATAR_CHECK_INPUT(!base.empty() && base.type() == CV_8UC3 && base.size() == warp.bgr.size())
      << "detail: the base frame must be BGR8 of the warp's size";
  cv::Mat b, w, out;
  base.convertTo(b, CV_32FC3);
  warp.bgr.convertTo(w, CV_32FC3);
  cv::Mat weight3;
  cv::cvtColor(warp.weight, weight3, cv::COLOR_GRAY2BGR);
  cv::Mat blended = b + weight3.mul(w - b);
  blended.convertTo(out, CV_8UC3);  // rounds and saturates
  if (alpha != nullptr && !alpha->empty()) {
    AVATAR_CHECK_INPUT(alpha->type() == CV_8UC1 && alpha->size() == base.size()) << "detail: alpha must be CV_8UC1";
    cv::Mat warp_alpha;
    warp.weight.convertTo(warp_alpha, CV_8UC1, 255.0);
    cv::max(*alpha, warp_alpha, *alpha);
  }
  return out;
}

cv::Mat PaintCavity(const cv::Mat& frame, const FaceWarp& warp) {
  AVATAR_CHECK_INPUT(!frame.empty() && frame.type() == CV_8UC3) << "detail: the frame must be BGR8";
  if (warp.cavity.empty() || cv::countNonZero(warp.cavity) == 0) return frame;
  AVATAR_CHECK_INPUT(warp.cavity.type() == CV_8UC1 && warp.cavity.size() == frame.size())
      << "detail: the cavity must be CV_8UC1 of the frame's size";
  FaceWarp layer;
  layer.bgr = cv::Mat(frame.size(), CV_8UC3, cv::Scalar(warp.cavity_bgr[0], warp.cavity_bgr[1], warp.cavity_bgr[2]));
  layer.weight = SoftenedByAPixel(warp.cavity);
  return Composite(frame, layer);
}

void ClearCarved(const FaceWarp& warp, cv::Mat* bgr, cv::Mat* alpha, cv::Mat* depth) {
  if (warp.carved.empty() || cv::countNonZero(warp.carved) == 0) return;
  AVATAR_CHECK_INPUT(warp.carved.type() == CV_8UC1) << "detail: the carved mask must be CV_8UC1";
  const cv::Size size = warp.carved.size();
  const cv::Mat keep = 1.0 - SoftenedByAPixel(warp.carved);
  if (bgr != nullptr && !bgr->empty()) {
    AVATAR_CHECK_INPUT(bgr->type() == CV_8UC3 && bgr->size() == size)
        << "detail: the frame must be BGR8 of the mask's size";
    cv::Mat f, keep3;
    bgr->convertTo(f, CV_32FC3);
    cv::cvtColor(keep, keep3, cv::COLOR_GRAY2BGR);
    f = f.mul(keep3);
    f.convertTo(*bgr, CV_8UC3);
  }
  if (alpha != nullptr && !alpha->empty()) {
    AVATAR_CHECK_INPUT(alpha->type() == CV_8UC1 && alpha->size() == size)
        << "detail: alpha must be CV_8UC1 of the mask's size";
    cv::Mat f;
    alpha->convertTo(f, CV_32FC1);
    f = f.mul(keep);
    f.convertTo(*alpha, CV_8UC1);
  }
  if (depth != nullptr && !depth->empty()) {
    AVATAR_CHECK_INPUT(depth->type() == CV_32FC1 && depth->size() == size)
        << "detail: depth must be CV_32FC1 of the mask's size";
    depth->setTo(std::numeric_limits<float>::infinity(), warp.carved);
  }
}

}  // namespace avatar::compose
