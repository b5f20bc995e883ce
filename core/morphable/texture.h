#pragma once
// Face texture sampled from the source image: a UV texture over the MediaPipe UV layout, filled
// from the part of the face visible in the fitted view (hidden texels are inpainted), plus
// per-vertex colours.

#include <vector>

#include <opencv2/core.hpp>

#include "core/morphable/fitter.h"
#include "core/morphable/morphable_model.h"

namespace avatar::morphable {

struct Texture {
  cv::Mat uv_image;                      // [T,T] CV_32FC3 BGR in [0,1] (may be empty: use vertex colours)
  cv::Mat uv_visible;                    // [T,T] CV_8UC1, 255 where sampled from the image, 0 inpainted/outside
  std::vector<cv::Vec3f> vertex_colors;  // [468] BGR in [0,1]
};

struct TextureOptions {
  // Side of the square UV texture in texels (0: vertex colours only).
  int size = 256;
  // Depth tolerance of the visibility test, as a fraction of the camera distance.
  double depth_tolerance = 0.01;

  template <typename V>
  void Visit(V&& v) {
    v("size", size, "Side of the UV texture in texels (0: vertex colours only)");
    v("depth_tolerance", depth_tolerance, "Visibility depth tolerance (fraction of the camera distance)");
  }
  void Validate() const;
};

// Samples the texture of `fit` from `bgr` (CV_8UC3, the image the fit refers to). Throws
// InvalidInput when the image size differs from fit.image_size or the image is empty.
Texture SampleTexture(const MorphableModel& model, const FitResult& fit, const cv::Mat& bgr,
                      const TextureOptions& options = {});

// A uniform grey texture (for geometry-only renders).
Texture UniformTexture(const cv::Vec3f& bgr = {0.7f, 0.7f, 0.7f});

}  // namespace avatar::morphable
