#pragma once
// Geometry on facemesh landmarks: the regions of the 468-point topology we use, head pose,
// the aligned-crop template, eye/mouth masks and the 68-point subset matching dlib/iBUG.

#include <array>
#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"

namespace avatar::face {

// Facemesh vertex indices (MediaPipe topology). "Right"/"left" are the subject's: the right
// eye appears on the image's left in a frontal photo.
namespace mesh_index {
inline constexpr int kNoseTip = 1;
inline constexpr int kForehead = 10;
inline constexpr int kChin = 152;
inline constexpr int kRightEyeOuter = 33;
inline constexpr int kLeftEyeOuter = 263;
inline constexpr int kMouthRight = 61;   // subject's right mouth corner
inline constexpr int kMouthLeft = 291;
// Closed contours, in order around each region.
const std::vector<int>& RightEye();
const std::vector<int>& LeftEye();
const std::vector<int>& RightBrow();
const std::vector<int>& LeftBrow();
const std::vector<int>& LipsOuter();
// The inner lip line (the mouth's opening), from the subject's right corner over the upper lip.
const std::vector<int>& LipsInner();
// 68 vertices in iBUG-68 order (jaw 0-16, brows 17-26, nose 27-35, eyes 36-47, mouth 48-67),
// chosen by anatomy for the cross-check against dlib's 68-point predictor.
const std::array<int, 68>& Ibug68();
}  // namespace mesh_index

// Centre of a region: mean of its vertices' x, y.
cv::Point2f RegionCentre(const Landmarks& lm, const std::vector<int>& region);

// Rough head rotation from the mesh: the face frame is built from the eye line (33 -> 263) and
// the forehead -> chin line (10 -> 152) with facemesh's depth, then read as yaw/pitch/roll.
// Roll > 0: the face is rotated clockwise in the image. Throws InvalidInput on degenerate input.
HeadPose HeadPoseFromLandmarks(const Landmarks& lm);

// The aligned-crop template (FFHQ-style, as used to build FFHQ and, re-cropped, EG3D's data):
// with e = midpoint of the eye centres, m = midpoint of the mouth corners,
//   d_eye = right-of-image eye - left-of-image eye, d_mouth = m - e,
//   x = normalise(d_eye - rot90(d_mouth)) * max(2.0 |d_eye|, 1.8 |d_mouth|), y = rot90(x),
//   centre c = e + 0.1 d_mouth;
// the square with corners c -/+ x -/+ y maps to [0,size]^2 (eyes level, face centred).
// `scale` > 1 zooms out around the same centre. Returns image -> crop pixels.
cv::Matx23d CropTransform(const Landmarks& image_landmarks, int size, double scale = 1.0);

// Least-squares similarity (rotation, uniform scale, translation) mapping src to dst (Umeyama).
cv::Matx23d SimilarityFromPoints(const std::vector<cv::Point2f>& src, const std::vector<cv::Point2f>& dst);

// Landmarks moved by an affine transform (z scaled by its uniform scale).
Landmarks TransformLandmarks(const Landmarks& lm, const cv::Matx23d& m);

// Eye, brow and lip polygons filled (255) on a size x size CV_8UC1 mask, then dilated by a
// disc of radius `dilation_px` (our stand-in for a face-parsing network's eye/mouth classes).
cv::Mat EyeMouthMask(const Landmarks& crop_landmarks, int size, int dilation_px);

}  // namespace avatar::face
