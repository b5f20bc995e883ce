#pragma once
// The photo's pixels carried to a new view through the network's own rendered depth: a 2.5D
// proxy for what the face mesh does not cover (hair, ears, neck, shoulders). A target pixel that
// the network renders opaque is lifted to 3D with its depth along the ray, projected into the
// source camera, and looks the photo up there when the photo saw that point (its distance from
// the source camera within a tolerance of the network's source-view depth) and it belongs to the
// person (matte). Both depth maps are smoothed first (the volume render is 32 px with the bundled
// model: its depth upsampled by nearest neighbour would warp in blocks).
//
// The network's silhouette is not the person's: its opacity fades on the shoulders, the neck and
// stray hair that the photo's matte keeps. So the proxy is the photo's whole person: the source
// depth is filled over the matte from the network's depth around it (push-pull), and the person's
// pixels, lifted with it, are splatted into the target view (z-buffered); a target pixel that the
// network leaves transparent but the splat covers is opaque with the splat's depth. At the source
// view this gives the matted photo back.

#include <vector>

#include <opencv2/core.hpp>

#include "core/compose/face_detail.h"
#include "core/morphable/camera_label.h"

namespace avatar::compose {

struct DepthDetailOptions {
  // Visibility tolerance: a point farther from the source camera than the source depth plus this
  // fraction of the camera distance (2.7) was hidden in the photo.
  double depth_tolerance = 0.03;
  // Opacity (0..255) below which a target pixel is background.
  int min_alpha = 128;
  // Matte value below which a photo pixel is background.
  float min_matte = 0.5f;
  // Beyond the network's silhouette (extend_to_matte): matte value down to which the photo's
  // outline is carried, weighted by the matte, so that the frame keeps the photo's soft edge.
  float outline_matte = 0.02f;
  // Smoothing of both depth maps (Gaussian sigma) as a fraction of the map's height.
  double depth_smoothing = 0.02;
  // Feather width of the warp's edge, as a fraction of the output height.
  double feather = 0.015;
  // Whether the photo's person beyond the network's silhouette is part of the proxy (see above).
  bool extend_to_matte = true;
  // Matte value below which a photo pixel is surely background: a pixel the network renders
  // opaque whose surface point the photo sees against such a pixel lies in empty space (the
  // photo's ray through it met no person), so the frame clears it (FaceWarp::carved). < 0: off.
  float carve_matte = 0.25f;

  // Throws InvalidOptions.
  void Validate() const;
};

// A source view's depth: along each pixel's ray, +inf (or any non-finite value) where empty.
struct ViewDepth {
  morphable::CameraLabel camera{};
  cv::Mat depth;  // CV_32FC1
};

class DepthDetail {
 public:
  // `photo` (CV_8UC3) and `matte` (CV_32FC1 in [0,1] of the photo's size; empty = all person) are
  // the aligned crop seen by `source.camera`; `source.depth` is the network's depth at that camera
  // (any size; the photo's aspect). Throws InvalidInput for mismatched sizes or types, a source
  // depth without any finite value, or a bad camera.
  DepthDetail(cv::Mat photo, cv::Mat matte, ViewDepth source, const DepthDetailOptions& options = {});

  // The photo warped to `target.camera` through `target.depth`, at the target depth's size,
  // where `alpha` (CV_8UC1, same size) is opaque and, with extend_to_matte, where the photo's
  // person lands. `face` of the result marks those pixels; beyond the network's silhouette the
  // weight is the photo's matte (its soft outline); `carved` marks the network's opaque pixels
  // that the photo shows as empty space (carve_matte).
  // Outputs finite; all invalid when nothing is opaque or the depth is empty.
  FaceWarp Warp(const ViewDepth& target, const cv::Mat& alpha) const;

 private:
  // The photo's person splatted into `size` at `camera`: CV_32FC1 distance from the camera
  // (+inf where nothing lands).
  cv::Mat SplatPerson(const morphable::PinholeCamera& camera, cv::Size size) const;

  cv::Mat photo_;
  cv::Mat matte_;
  ViewDepth source_;   // depth smoothed
  cv::Mat filled_;     // CV_32FC1 the smoothed source depth with every gap filled (push-pull)
  DepthDetailOptions options_;
};

// The world point at distance `depth` along the ray of pixel (x, y) (centres at i + 0.5) of an
// image of `size` seen by `camera` (unit direction, as the volume renderer casts it). The one
// lift of a depth map: the depth warp and the exported head mesh use it.
class PixelRays {
 public:
  explicit PixelRays(const morphable::PinholeCamera& camera)
      : camera_(camera), k_inv_(camera.k_normalised.inv()), cam_to_world_(camera.world_to_cam.t()) {}
  cv::Vec3d Point(double x, double y, cv::Size size, double depth) const {
    cv::Vec3d dir = cam_to_world_ * (k_inv_ * cv::Vec3d((x + 0.5) / size.width, (y + 0.5) / size.height, 1.0));
    return camera_.centre + depth / cv::norm(dir) * dir;
  }

 private:
  morphable::PinholeCamera camera_;
  cv::Matx33d k_inv_, cam_to_world_;
};

// Non-finite depth filled from its finite neighbours and smoothed (sigma = `smoothing` x height);
// pixels with no finite value within reach stay +inf. For tests and the warp.
cv::Mat SmoothDepth(const cv::Mat& depth, double smoothing);

// The fitted face mesh's depth at `camera` (world vertices and triangles of the morphable model)
// in an image of `size`: distance along each pixel's ray, as the network's depth and PixelRays
// count it; +inf where the mesh does not cover. Throws InvalidInput for a bad camera.
cv::Mat MeshRayDepth(const morphable::CameraLabel& camera, const std::vector<cv::Point3f>& world,
                     const std::vector<cv::Vec3i>& triangles, cv::Size size);

// How far to move the network's depth along the rays so that it meets the fitted face mesh: the
// median of (mesh depth - network depth) over the pixels where the mesh covers and the network
// is opaque (`alpha` >= min_alpha), all maps of one size. The bundled network's surface lies
// 0.03-0.05 (of the 2.7 camera distance) behind the face mesh: lifted with it, hair and temples
// turn on a smaller circle than the face and slide across it at +-30 degrees (issue 32). 0 when
// fewer than `min_pixels` pixels are shared. Throws InvalidInput for maps of different sizes.
double FaceDepthOffset(const cv::Mat& network_depth, const cv::Mat& alpha, const cv::Mat& mesh_depth,
                       int min_alpha = 128, int min_pixels = 32);

// FaceDepthOffset spread over one view (CV_32FC1 of the mask's size): `offset` where `face`
// (CV_8UC1, non-zero = the face mesh covers) and, away from it, offset x exp(-(d / (reach x
// height))^2) with d the distance to the face in pixels: the face mesh says where the head is near
// the face, not at the shoulders. reach <= 0: the offset everywhere; no face: zeros.
cv::Mat FaceOffsetField(const cv::Mat& face, double offset, double reach);

// Every non-finite pixel of a CV_32FC1 map filled from the finite ones (push-pull over an image
// pyramid: the nearer values weigh more); finite pixels keep their value. All +inf when no pixel
// is finite.
cv::Mat FillGaps(const cv::Mat& depth);

}  // namespace avatar::compose
