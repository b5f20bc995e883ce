#pragma once
// Face analysis of a photo or a video as `avatar-studio analyze` reports it: for a photo every
// face (box, score, landmarks, pose), the main face's aligned crop, matte, masks and a landmark
// overlay, with per-stage times; for a video the tracked face of each frame (smoothed landmarks
// and pose), handed out one frame at a time so that memory stays flat with the clip's length.

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_analyzer.h"
#include "core/util/run_context.h"

namespace avatar {

struct MediaAnalysisOptions {
  // The photo or video to analyse.
  std::string input;
  // Folder for crop.png, crop_unmatted.png, matte.png, eye_mouth_mask.png, overlay.png ("" = none);
  // a video writes only overlay.png (its first frame).
  std::string out_dir;
  // Video: analyse at most this many frames (0 = all).
  int max_frames = 0;
  // Face analysis settings.
  face::FaceAnalyzerOptions face;

  // Throws InvalidOptions.
  void Validate() const;
};

// One face of a photo.
struct PhotoFace {
  face::Detection detection;
  bool selected = false;            // the analysed (main) face
  face::Landmarks landmarks;        // image pixels
  std::optional<face::HeadPose> pose;  // none when the landmarks give no pose
};

struct PhotoAnalysis {
  int width = 0, height = 0;
  std::vector<PhotoFace> faces;     // Detect() order
  int selected = -1;
  face::AlignedPortrait portrait;   // of the selected face
  // Stage times in ms, in order: load_image, load_models, the analyser's stages,
  // other_faces_mesh, total.
  std::vector<face::StageTiming> timings;
};

// Analyses a photo and writes the images into options.out_dir (when set). Throws InvalidOptions;
// Io (unreadable photo, output folder); InvalidInput naming the photo (no usable face);
// MissingData (face models); Cancelled.
PhotoAnalysis AnalysePhoto(const MediaAnalysisOptions& options, RunContext& ctx);

struct VideoAnalysisInfo {
  int width = 0, height = 0;
  double fps = 25.0;  // the clip's rate (25 when the file gives none)
};

struct VideoFrameAnalysis {
  int64_t index = 0;
  double time = 0.0;  // seconds
  face::TrackedFace face;
};

struct VideoAnalysis {
  VideoAnalysisInfo info;
  int64_t frames = 0, frames_with_face = 0, redetections = 0;
  double decode_ms_per_frame = 0.0, track_ms_per_frame = 0.0;
  double seconds = 0.0;  // wall time of the whole analysis
};

// Tracks the face through a video. `on_start` (may be empty) gets the clip's size and rate before
// the first frame, `on_frame` each frame as it is tracked. Reports progress to ctx. Throws
// InvalidOptions; Io / InvalidInput naming the video (unreadable, no frames); MissingData;
// Cancelled.
VideoAnalysis AnalyseVideo(const MediaAnalysisOptions& options, RunContext& ctx,
                           const std::function<void(const VideoAnalysisInfo&)>& on_start,
                           const std::function<void(const VideoFrameAnalysis&)>& on_frame);

}  // namespace avatar
