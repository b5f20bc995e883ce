#pragma once
// Face analysis: what a dropped photo or video becomes before the avatar model sees it.
//   Detect   BlazeFace (full-range on the whole image and, for large images, on overlapping
//            tiles; short-range on the whole image), weighted NMS, main face first.
//   Mesh     468-point facemesh, two passes: a rotated crop from the detection, then a
//            re-crop from the first pass's landmarks.
//   Portrait pose, FFHQ-style aligned 512x512 crop (face_geometry.h), person matte (selfie
//            model), eye/mouth masks from landmark polygons, identity embedding (fr_feature.onnx,
//            identity_net.h).
// Models load once per FaceAnalyzer; every const method is thread-safe.

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/face/one_euro.h"
#include "core/util/run_context.h"

namespace avatar::face {

struct FaceAnalyzerOptions {
  // Folder with models/ ("" = AVATAR_DATA_DIR, then ~/.cache/avatar-studio).
  std::string data_dir;
  // Detection score threshold in [0,1].
  float min_score = 0.6f;
  // Overlap above which detections are merged (weighted NMS).
  float nms_iou = 0.3f;
  // Also run the full-range detector on overlapping tiles of large images (finds small faces).
  bool tile_large_images = true;
  // AnalyzePortrait refuses faces whose box side is below this many pixels (too few pixels for
  // the landmarks to be trusted).
  int min_face_px = 24;
  // Faces from min_face_px up to this box side are accepted with a warning: their crop is
  // upsampled, so the avatar comes out soft.
  int sharp_face_px = 48;
  // Which face AnalyzePortrait uses: -1 = the main face (largest and most central), k = the
  // k-th face of Detect() (which lists the main face first).
  int face_index = -1;
  // Side of the aligned crop in pixels.
  int crop_size = 512;
  // Zoom-out of the crop template (1 = FFHQ-style framing).
  double crop_scale = 1.0;
  // Dilation radius of the eye/mouth mask at crop_size 512 (scaled with the crop).
  int mask_dilation_px = 8;
  // Compute the person matte (else the matte is all ones).
  bool matte = true;
  // Compute the identity embedding.
  bool embedding = true;
  // Landmarks whose face-presence confidence is below this are refused.
  float min_mesh_confidence = 0.5f;
  // Below this face-presence confidence the detection is not a face at all, and AnalyzePortrait
  // says "no face found" (detector false positives and a drawn smiley measured <= 0.16, real
  // faces of the packaged photos >= 0.61; docs/DEVIATIONS.md).
  float min_face_presence = 0.25f;
  // Faces turned further than this (|yaw| degrees, as measured from the landmarks) are refused by
  // AnalyzePortrait: on renders at known yaw, 35 measured is about 50 degrees of true turn,
  // where the landmarks' error has grown to 3.5x the frontal one (docs/DEVIATIONS.md).
  float max_abs_yaw = 35.0f;

  template <typename V>
  void Visit(V&& v) {
    v("min_score", min_score, "Face detection score threshold in [0,1]");
    v("nms_iou", nms_iou, "Overlap above which detections are merged");
    v("tile_large_images", tile_large_images, "Also detect on overlapping tiles of large images");
    v("min_face_px", min_face_px, "Smallest face (box side, pixels) accepted for a portrait");
    v("sharp_face_px", sharp_face_px, "Smaller faces are accepted with a warning that the result will be soft");
    v("face_index", face_index, "Face to analyse: -1 = main face, k = k-th detected face");
    v("crop_size", crop_size, "Side of the aligned crop in pixels");
    v("crop_scale", crop_scale, "Zoom-out of the crop template (1 = FFHQ framing)");
    v("mask_dilation_px", mask_dilation_px, "Eye/mouth mask dilation radius at 512 px");
    v("matte", matte, "Compute the person matte");
    v("embedding", embedding, "Compute the identity embedding");
    v("min_mesh_confidence", min_mesh_confidence, "Refuse landmarks below this confidence");
    v("min_face_presence", min_face_presence, "Below this landmark confidence the detection is not a face");
    v("max_abs_yaw", max_abs_yaw, "Refuse faces turned further than this (degrees)");
  }
  void Validate() const;  // throws InvalidOptions
};

struct StageTiming {
  std::string stage;  // e.g. "detect"
  double ms = 0.0;    // wall time in milliseconds
};

// Everything AnalyzePortrait measured besides the portrait itself.
struct PortraitReport {
  std::vector<Detection> faces;  // every face found, Detect() order (main face first)
  int selected = -1;             // index into faces of the analysed face
  Landmarks image_landmarks;     // the analysed face's landmarks in image pixels
  std::vector<StageTiming> timings;
};

class FaceAnalyzer {
 public:
  // Loads the models from the data folder. Throws MissingData/ModelLoad naming the missing or
  // broken file and "run scripts/setup"; InvalidOptions for bad options.
  explicit FaceAnalyzer(const FaceAnalyzerOptions& options = {});
  ~FaceAnalyzer();
  FaceAnalyzer(const FaceAnalyzer&) = delete;
  FaceAnalyzer& operator=(const FaceAnalyzer&) = delete;

  const FaceAnalyzerOptions& Options() const { return options_; }

  // Faces in a BGR8 image, main face first (then by decreasing rank: size and centrality).
  // Throws InvalidInput for an empty or non-BGR8 image.
  std::vector<Detection> Detect(const cv::Mat& bgr) const;

  // Two-pass 468-point mesh of `face`, in image pixel coordinates.
  Landmarks Mesh(const cv::Mat& bgr, const Detection& face) const;

  // One mesh pass from a crop around `previous` landmarks (for tracking).
  Landmarks MeshFromLandmarks(const cv::Mat& bgr, const Landmarks& previous) const;

  // The main (or options.face_index-th) face -> aligned crop, matte, masks, landmarks in crop
  // pixels, pose, embedding; a small (soft) face adds a line to AlignedPortrait::warnings.
  // Throws InvalidInput (no face, tiny face, unreliable landmarks, profile view, bad
  // face_index), Cancelled through ctx.
  AlignedPortrait AnalyzePortrait(const cv::Mat& bgr, RunContext& ctx, PortraitReport* report = nullptr) const;

  // Person matte of a BGR8 image: CV_32FC1 in [0,1], same size.
  cv::Mat Matte(const cv::Mat& bgr) const;

  // 512-d L2-normalised identity embedding (IdentityNet, fr_feature.onnx) of the face with these
  // image landmarks.
  std::vector<float> Embedding(const cv::Mat& bgr, const Landmarks& image_landmarks) const;

 private:
  struct Models;
  std::unique_ptr<Models> models_;
  FaceAnalyzerOptions options_;
  Landmarks RunMesh(const cv::Mat& bgr, const cv::Point2f& centre, float size, float angle) const;
};

// Cosine similarity of two identity embeddings in [-1,1] (1 = same direction); the CSIM
// metric. Throws InvalidInput for empty or mismatched vectors.
float IdentitySimilarity(const std::vector<float>& a, const std::vector<float>& b);

// One analyzer per distinct options (data folder included) for the whole process: the models
// load once and every caller (the session, the studio's workers, the command line) shares it;
// its const methods are thread-safe. Throws what the constructor throws (nothing is kept then).
const FaceAnalyzer& SharedFaceAnalyzer(const FaceAnalyzerOptions& options);

// The main face: the detection with the best rank (box side / image long side minus half the
// distance of its centre from the image centre / image long side). -1 if `faces` is empty.
int MainFaceIndex(const std::vector<Detection>& faces, const cv::Size& image);

struct FaceTrackerOptions {
  // Below this mesh confidence the face counts as lost and is re-detected.
  float min_confidence = 0.5f;
  // Smooth landmarks and pose with One-Euro filters.
  bool smooth = true;
  // Landmark filter (pixels): min cutoff 1.5 Hz, beta 0.02 per px/s.
  OneEuroParams landmark_filter{1.5, 0.02, 1.0};
  // Pose filter (degrees): min cutoff 1.0 Hz, beta 0.05 per deg/s.
  OneEuroParams pose_filter{1.0, 0.05, 1.0};
};

// One frame's result.
struct TrackedFace {
  bool found = false;       // false: no face in this frame (landmarks empty)
  bool redetected = false;  // the detector ran on this frame (first frame or track lost)
  Landmarks landmarks;      // smoothed, frame pixels
  Landmarks raw;            // as measured
  HeadPose pose;            // smoothed
  float confidence = 0.0f;  // mesh face-presence confidence in [0,1]
};

// Tracks the main face through a video: the mesh of frame t is cropped from the landmarks of
// frame t-1; the detector runs on the first frame and whenever the confidence drops.
class FaceTracker {
 public:
  explicit FaceTracker(const FaceAnalyzer& analyzer, const FaceTrackerOptions& options = {});
  ~FaceTracker();
  // Processes the next frame (BGR8) seen at `time_seconds` (increasing).
  TrackedFace Track(const cv::Mat& bgr, double time_seconds);
  void Reset();

 private:
  const FaceAnalyzer& analyzer_;
  FaceTrackerOptions options_;
  Landmarks previous_;
  bool tracking_ = false;
  std::vector<OneEuroFilter> filters_;  // 3 per landmark, then yaw, pitch, roll
};

}  // namespace avatar::face
