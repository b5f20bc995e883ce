#pragma once
// Synthetic multi-view heads for training (issue 11): a textured 2.5D head made from one real
// portrait and its morphable fit, rendered with the morphable rasterizer at other EG3D cameras and
// with other expressions.
//
// Geometry: one vertex per pixel corner of the portrait (the image the fit refers to, any size).
// Inside the fitted morphable face the depth is the face's; elsewhere in the person matte (hair,
// ears, neck) a smooth surface continues the face (the face's depth offset from a head-sized
// ellipsoid, spread outwards and fading) and bends back in a band along the silhouette. Every
// quad whose pixel has matte > 0 is kept, so the render at the source camera covers exactly the
// matte. Texture: the photo itself (colour, eye/mouth mask and matte as channels; the matte
// makes the alpha), where the surface was seen at a grazing angle the colour of its mirror point
// (about the face's symmetry plane x = 0) is used when that point was seen well.
// Expressions: each vertex follows the morphable face's vertex displacements (face vertices
// through their triangle's barycentrics; the others through the nearest face pixel with a
// Gaussian falloff).
//
// World frame and cameras are those of the fit (core/morphable: world = scale * model, camera
// label in render::Camera's convention), so the labels of synthetic renders match the real data.

#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "core/morphable/camera_label.h"
#include "core/morphable/fitter.h"
#include "core/morphable/morphable_model.h"

namespace avatar {

struct SyntheticHeadOptions {
  // Width of the Gaussian falloff (sigma) of the face's depth offset and of its expression
  // displacements into the surrounding surface, as a fraction of the image side.
  double falloff = 0.08;
  // Width of the band along the silhouette in which the surface bends back, fraction of the side.
  double bend_width = 0.05;
  // Depth the surface gains at the silhouette, as a fraction of the ellipsoid's depth semi-axis.
  double bend_depth = 0.8;
  // Texels whose surface normal makes a cosine below this with the source view count as unseen
  // and take the colour of their mirror point when that point is seen at a cosine >= 2x this.
  double grazing_cosine = 0.15;
  // Texture side relative to the image side (colour upsampled bicubically).
  int texture_scale = 2;

  // Throws InvalidOptions.
  void Validate() const;
};

struct SyntheticHead {
  std::vector<cv::Point3f> vertices;  // [V] world positions (fit's world frame)
  std::vector<cv::Point2f> uv;        // [V] texture position in [0,1]^2 (x right, y down)
  std::vector<cv::Vec3i> triangles;   // [T] vertex indices
  cv::Mat colour;                     // [T,T] CV_32FC3 BGR in [0,1] (the photo, mirror-filled)
  cv::Mat aux;                        // [T,T] CV_32FC2: eye/mouth mask, matte, in [0,1]
  // Expression binding: vertex v moves by weight[v] * sum_k bary[v][k] * delta(face_vertex[v][k]).
  std::vector<cv::Vec3i> face_vertex;  // [V] morphable vertices
  std::vector<cv::Vec3f> face_bary;    // [V]
  std::vector<float> face_weight;      // [V] 1 on the face, falling off outside
  int mirrored_texels = 0;             // texels filled from their mirror point
};

struct SyntheticView {
  cv::Mat image;      // [S,S] CV_32FC3 BGR in [0,1] (not premultiplied; 0 where alpha is 0)
  cv::Mat alpha;      // [S,S] CV_32FC1 in [0,1]: coverage x matte channel
  cv::Mat eye_mouth;  // [S,S] CV_32FC1 in [0,1]
  cv::Mat depth;      // [S,S] CV_32FC1 camera depth of the nearest surface (0 where empty)
};

// Builds the head of one portrait. `bgr` CV_8UC3 (or CV_32FC3 in [0,1]) is the image the fit's
// camera refers to (any square size; the fit's image_size is not used), `matte` CV_32FC1 in
// [0,1] and `eye_mouth` CV_8UC1 or CV_32FC1 of the same size (may be empty). Throws InvalidInput
// (sizes, no face in view, empty matte).
SyntheticHead BuildSyntheticHead(const morphable::MorphableModel& model, const morphable::FitResult& fit,
                                 const cv::Mat& bgr, const cv::Mat& matte, const cv::Mat& eye_mouth,
                                 const SyntheticHeadOptions& options = {});

// Head vertices with the face's expression changed from fit.beta to `beta` (fit.beta: the
// head's own vertices).
std::vector<cv::Point3f> HeadVertices(const morphable::MorphableModel& model, const morphable::FitResult& fit,
                                      const SyntheticHead& head, const morphable::Beta& beta);

// Renders the head (with `vertices`, e.g. from HeadVertices) at `camera` through the morphable
// rasterizer with `supersample`^2 samples per pixel. Throws InvalidInput.
SyntheticView RenderSyntheticView(const SyntheticHead& head, const std::vector<cv::Point3f>& vertices,
                                  const morphable::CameraLabel& camera, cv::Size size, int supersample = 2);

// The label of the same camera mirrored about the world plane x = 0, with the image flipped
// horizontally (a flipped render of a mirrored head).
morphable::CameraLabel MirroredLabel(const morphable::CameraLabel& label);

// Expression coefficients of the mirrored face: the least-squares (prior-regularised) beta whose
// displacements equal the mirror image of `beta`'s (vertex i takes vertex mirror[i]'s, x negated).
morphable::Beta MirroredExpression(const morphable::MorphableModel& model, const morphable::Beta& beta);

// Camera yaw and pitch (degrees) of a label: the centre's azimuth about +y and elevation.
cv::Vec2d LabelYawPitch(const morphable::CameraLabel& label);

}  // namespace avatar
