#pragma once
// The photo's own pixels carried to a new view and expression through the fitted morphable face
// mesh (explicit correspondence): a target pixel covered by the mesh at the target camera and
// expression looks up the same barycentric point of the mesh at the source camera and expression
// in the aligned photo, when the photo saw that point (source depth test) and it belongs to the
// person (matte). Where an eye or the mouth changes with the expression (its contour on the mesh
// moves), the photo cannot show its inside (a closed eye has no pupil to open): the opening of that
// eye or of the mouth in the target is marked `changed` and left to the base frame (the network's
// expression branch) while lids and lips follow the mesh; with changed_eye_mouth "network" the
// whole eye or mouth is.

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/morphable/morphable.h"
#include "core/morphable/rasterizer.h"

namespace avatar::compose {

struct FaceDetailOptions {
  // Depth tolerance of the visibility test, as a fraction of the camera distance (2.7).
  double depth_tolerance = 0.01;
  // Matte value below which a photo pixel is background.
  float min_matte = 0.5f;
  // Feather width of the warp's edge, as a fraction of the output height.
  double feather = 0.01;
  // An eye or the mouth has changed when a vertex of its contour moves by more than this between
  // the source and the target expression, as a fraction of the distance between the eyes' outer
  // corners. On the bundled morphable model a blink moves the lid by 0.13, jawOpen and smile the
  // lips by 0.16, a smile the lower lids by 0.04 and eyesWide the lids by 0.016 (printed by
  // pipeline/Detail.ChangedEyesAndMouthComeFromTheBaseFrame): blinks and mouth motion count.
  double eye_mouth_motion = 0.05;
  // What a changed eye or mouth shows: "mesh" (the photo's lids and lips follow the mesh; the
  // openings - inside the lid margin, inside the inner lip line - come from the base frame, since
  // the photo's eye or mouth interior belongs to the other expression) or "network" (the whole
  // eye and mouth, with a margin, come from the base frame).
  std::string changed_eye_mouth = "mesh";
  // An eye of the photo whose lid gap over its width (the photo's facemesh landmarks, 159-145 over
  // 33-133 and 386-374 over 263-362) is below this is closed: wherever the target's eye is open
  // (the same ratio on the target mesh above it) its opening comes from the base frame too, even
  // when the fit did not register the blink. Open eyes measure 0.25-0.35.
  double closed_eye_ratio = 0.12;
  // With "mesh", a changed mouth's opening where the mesh has its hole (between the inner lip
  // lines) shows the mouth's dark interior - the photo's lip colour times this shade - rather than
  // the base frame, whose own mouth may not open (the bundled network's does not). < 0 leaves it to
  // the base frame.
  double mouth_cavity_shade = 0.3;

  // Throws InvalidOptions.
  void Validate() const;
};

// The photo warped to one target view, at the output size.
struct FaceWarp {
  cv::Mat bgr;     // [H,W] CV_8UC3 warped photo (black where not valid)
  cv::Mat valid;   // [H,W] CV_8UC1 255 where the photo saw the target pixel's surface point
  cv::Mat weight;  // [H,W] CV_32FC1 feathered blend weight in [0,1] (0 outside `valid`)
  cv::Mat face;    // [H,W] CV_8UC1 255 where the face mesh covers the target pixel
  // [H,W] CV_8UC1 255 where the face mesh's surface point lies in the photo's eye/mouth region
  // (seen or not); empty for warps without a face mesh.
  cv::Mat eye_mouth;
  // [H,W] CV_8UC1 255 on the target's eyes and mouth where they changed with the expression: no
  // layer of the photo may draw there (ExcludeRegion); empty for warps without a face mesh.
  cv::Mat changed;
  // [H,W] CV_8UC1 255 on the opened mouth's interior (inside the changed inner lip line), which
  // no photo pixel shows: PaintCavity draws it in `cavity_bgr`; empty for warps without a face mesh.
  cv::Mat cavity;
  cv::Vec3b cavity_bgr{0, 0, 0};
  // [H,W] CV_8UC1 255 where the frame below is opaque but the photo shows empty space there
  // (DepthDetail only; ClearCarved removes it); empty for other warps.
  cv::Mat carved;
  // [H,W] CV_8UC3 the fitted face's texture over the whole face mesh (where `face`), looked up
  // through the same rasterisation as the warp; empty unless FaceDetail::SetFillTexture was called.
  cv::Mat fill_bgr;
};

class FaceDetail {
 public:
  // `photo` is the aligned crop the fit refers to (CV_8UC3, fit.image_size), `matte` its person
  // matte (CV_32FC1 in [0,1], same size; empty = all person), `eye_mouth` its eye/mouth mask
  // (CV_8UC1; empty = none). Renders the source view's depth once (the per-avatar bake). The
  // model must outlive this object. Throws InvalidInput for mismatched sizes or types.
  // `photo_landmarks` (facemesh points in the photo's pixels; empty = unknown) tell closed eyes.
  FaceDetail(const morphable::MorphableModel& model, morphable::FitResult fit, cv::Mat photo, cv::Mat matte,
             cv::Mat eye_mouth, const FaceDetailOptions& options = {},
             const std::vector<cv::Point3f>& photo_landmarks = {});

  // Whether the photo's right / left eye (subject's) is closed (closed_eye_ratio).
  bool PhotoEyeClosed(int eye) const { return eye_closed_[eye]; }

  // The photo warped to `camera` with expression `beta` (the model's expression coefficients,
  // absolute) at `size`. Outputs are finite; an empty result (all invalid) when the mesh is not
  // in view. Throws InvalidInput for a wrong beta length or a bad camera.
  FaceWarp Warp(const morphable::CameraLabel& camera, const morphable::Beta& beta, cv::Size size) const;

  const morphable::FitResult& fit() const { return fit_; }

  // Also look up `texture` (the fit's UV texture, or its vertex colours when it has no UV image)
  // over the whole face in every Warp (FaceWarp::fill_bgr): the fill of what the photo did not see,
  // at no second rasterisation of the mesh. Throws InvalidInput for a texture of another type.
  void SetFillTexture(const morphable::Texture& texture);

  // The largest motion of a region's vertices (mesh_index contour) from the source expression to
  // `target_world` (the mesh at the target expression, source pose), as a fraction of the eye
  // distance.
  double EyeMouthMotion(const std::vector<cv::Point3f>& target_world, const std::vector<int>& region) const;

 private:
  // `mouth` (may be null) gets the changed mouth's opening alone (mode "mesh"; zeros otherwise).
  cv::Mat ChangedEyeMouth(const std::vector<cv::Point3f>& target_world,
                          const std::vector<morphable::ScreenVertex>& target_screen, cv::Size size,
                          cv::Mat* mouth = nullptr) const;

  const morphable::MorphableModel& model_;
  morphable::FitResult fit_;
  cv::Mat photo_;                          // CV_8UC3
  cv::Mat matte_;                          // CV_32FC1
  cv::Mat eye_mouth_;                      // CV_8UC1
  FaceDetailOptions options_;
  std::vector<cv::Point3f> source_world_;  // mesh at the source expression, world
  cv::Mat source_depth_;                   // CV_32FC1 source-view depth of the mesh (+inf where empty)
  bool eye_closed_[2] = {false, false};    // the photo's right and left eye
  cv::Vec3b cavity_colour_{0, 0, 0};       // BGR of the mouth's interior
  bool fill_ = false;                      // SetFillTexture was called
  morphable::Texture fill_texture_;
};

// Lid gap over eye width of the subject's right (0) or left (1) eye from facemesh-ordered points
// (x, y used); 0 for a degenerate eye.
double EyeOpenRatio(const std::vector<cv::Point2d>& points, int eye);

// The warp of `photo` by per-pixel source positions (map_x, map_y: photo pixels, centres at
// i + 0.5; anything where `valid` is 0): one bilinear lookup, black outside `valid`, and the
// feathered weight (see FeatheredWeight for `open`). `face` is passed through.
FaceWarp WarpFromMaps(const cv::Mat& photo, const cv::Mat& map_x, const cv::Mat& map_y, cv::Mat valid, cv::Mat face,
                      double feather, const cv::Mat& open = cv::Mat());

// The blend weight of a valid mask (CV_8UC1, 255 = valid): 0 outside, rising to 1 over
// `feather` x height inside (CV_32FC1 in [0,1]). Pixels of `open` (CV_8UC1, may be empty: none)
// have nothing beneath them to blend with (the background beyond the person's silhouette), so the
// weight does not fade towards them: the photo's own outline stays sharp.
cv::Mat FeatheredWeight(const cv::Mat& valid, double feather, const cv::Mat& open = cv::Mat());

// Blends `warp` over `base` (CV_8UC3 of the same size): base where weight is 0, the warped photo
// where it is 1. Returns the composite; `alpha` (CV_8UC1, may be empty) gets at least the warp's
// weight where the face covers.
cv::Mat Composite(const cv::Mat& base, const FaceWarp& warp, cv::Mat* alpha = nullptr);

// `frame` (CV_8UC3 of the warp's size) with the warp's mouth interior painted in its colour, the
// edge softened by a pixel; the frame itself where the warp has no cavity.
cv::Mat PaintCavity(const cv::Mat& frame, const FaceWarp& warp);

// Clears the warp's carved pixels from a frame (BGR8 to black, alpha to 0, depth to +inf; each may
// be empty), their edge softened by a pixel. Nothing changes when the warp carved nothing.
void ClearCarved(const FaceWarp& warp, cv::Mat* bgr, cv::Mat* alpha, cv::Mat* depth);

// Removes `region` (CV_8UC1, 255 = excluded; empty = nothing) from a warp: not valid there, and
// its weight fades to 0 over `feather` x height towards the region, so the frame below shows
// there with a soft seam.
void ExcludeRegion(FaceWarp* warp, const cv::Mat& region, double feather);

}  // namespace avatar::compose
