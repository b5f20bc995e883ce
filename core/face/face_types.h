#pragma once
// Plain data exchanged between face analysis (core/face), the morphable model
// (core/morphable) and the pipeline. No torch types: every consumer can use these.

#include <array>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace avatar::face {

// Number of points of the MediaPipe / facemesh topology.
inline constexpr int kMeshPoints = 468;

// One detected face in the analysed image's pixel coordinates.
struct Detection {
  cv::Rect2f box;                         // Face box, pixels.
  float score = 0.0f;                     // Detector confidence in [0,1].
  std::array<cv::Point2f, 6> keypoints{}; // Blazeface order: right eye, left eye, nose, mouth, right ear, left ear.
};

// Dense landmarks of one face.
struct Landmarks {
  // kMeshPoints points in facemesh order. x, y: pixels of the image they refer to; z: relative
  // depth in the same pixel scale (facemesh convention: smaller z = closer to the camera).
  std::vector<cv::Point3f> points;
  float confidence = 0.0f;  // Face presence in [0,1] from the mesh network.
};

// Rough head rotation in degrees (yaw > 0: the face turns to the image's left; pitch > 0: up).
struct HeadPose {
  float yaw = 0.0f;
  float pitch = 0.0f;
  float roll = 0.0f;
};

// What the network and the morphable fitter need from one portrait: the aligned crop and
// everything measured on it.
struct AlignedPortrait {
  cv::Mat image;           // [512,512] CV_8UC3 BGR, background replaced by black using `matte`.
  cv::Mat image_unmatted;  // [512,512] CV_8UC3 BGR, the plain crop (for overlays and texture).
  cv::Mat matte;           // [512,512] CV_32FC1 person matte in [0,1].
  cv::Mat eye_mouth_mask;  // [512,512] CV_8UC1, 255 on eyes, brows, lips and inner mouth (dilated).
  Landmarks landmarks;     // In the crop's pixel coordinates.
  HeadPose pose;
  cv::Matx23d crop_from_image = cv::Matx23d::eye();  // Similarity transform: original pixels -> crop pixels.
  std::vector<float> embedding;                        // Identity embedding (512 (fr_feature), L2-normalised); empty if not computed.
  std::vector<std::string> warnings;                   // What the user should know about this portrait (e.g. a small face: soft result); one sentence each.
};

}  // namespace avatar::face
