#pragma once
// Face texture sampled from the source image: a UV texture over the MediaPipe UV layout, filled
// from the part of the face visible in the fitted view (hidden texels are inpainted), plus
// per-vertex colours.

#include <algorithm>
#include <vector>

#include <opencv2/core.hpp>

#include "core/morphable/fitter.h"
#include "core/morphable/morphable_model.h"

namespace avatar::morphable {

// Bilinear interpolation of `image` (pixel type T: cv::Vec3f, cv::Vec2f, cv::Vec3d, float, ...)
// at the continuous position (fx, fy), texel centres at integers, clamped to the border; weights
// and sums in T's channel type. The one texture sampler: the mesh renderer, the texture sampling
// of a photo and the data factory's synthetic heads all read images through it.
template <typename T>
T SampleBilinear(const cv::Mat& image, double fx, double fy) {
  using W = typename cv::DataType<T>::channel_type;
  fx = std::clamp(fx, 0.0, image.cols - 1.0);
  fy = std::clamp(fy, 0.0, image.rows - 1.0);
  const int x0 = static_cast<int>(fx), y0 = static_cast<int>(fy);
  const int x1 = std::min(x0 + 1, image.cols - 1), y1 = std::min(y0 + 1, image.rows - 1);
  const W ax = static_cast<W>(fx - x0), ay = static_cast<W>(fy - y0);
  return (1 - ay) * ((1 - ax) * image.at<T>(y0, x0) + ax * image.at<T>(y0, x1)) +
         ay * ((1 - ax) * image.at<T>(y1, x0) + ax * image.at<T>(y1, x1));
}

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
  // With a person matte: a point whose photo pixel's matte is below this was not seen (it takes
  // its mirrored texel or the inpainting like any hidden point).
  float min_matte = 0.5f;

  template <typename V>
  void Visit(V&& v) {
    v("size", size, "Side of the UV texture in texels (0: vertex colours only)");
    v("depth_tolerance", depth_tolerance, "Visibility depth tolerance (fraction of the camera distance)");
    v("min_matte", min_matte, "With a matte: value below which a photo pixel is background (not sampled)");
  }
  void Validate() const;
};

// Samples the texture of `fit` from `bgr` (CV_8UC3, the image the fit refers to); with `matte`
// (CV_32FC1 in [0,1] of the image's size) only from the person. Throws InvalidInput when the
// image size differs from fit.image_size, the image is empty or the matte is not of its size.
Texture SampleTexture(const MorphableModel& model, const FitResult& fit, const cv::Mat& bgr,
                      const TextureOptions& options = {}, const cv::Mat& matte = {});

// A uniform grey texture (for geometry-only renders).
Texture UniformTexture(const cv::Vec3f& bgr = {0.7f, 0.7f, 0.7f});

}  // namespace avatar::morphable
