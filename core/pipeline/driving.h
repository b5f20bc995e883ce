#pragma once
// Drivers: where an animation's per-frame expression and head pose come from. An export
// reads a driver front to back, one frame at a time, in constant memory. Two kinds:
//  - KeyframeDriver: a JSON file of timed keys (camera + named expression controls),
//    interpolated linearly;
//  - VideoDriver: a driving video read through DrivingVideo, the one seekable video driver
//    that the studio's preview uses too: each frame is analysed by a FrameAnalyzer (face
//    tracking + morphable fit) into an expression vector and a head pose, transferred
//    relative to a neutral frame or absolutely, held on frames with a missed face, and
//    smoothed over time.
// ComposeFrame is the one place that turns the source's pose, the user's view and a driver
// sample into what is rendered (preview, animate and the export dialog alike).

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/pipeline/frame_source.h"
#include "core/util/run_context.h"

namespace avatar {

class VideoReader;

// One frame of a driver.
struct DrivingSample {
  ViewPose pose;               // Head pose of the driver (relative to its neutral frame in relative mode).
  FrameExpression expression;  // Expression to apply.
  bool face_found = true;      // False when the analyser found no face (the previous sample is held).
};

struct DrivingOptions {
  // Transfer expressions and pose relative to the neutral frame (true) or as measured (false).
  bool relative = true;
  // Index of the driver frame taken as the neutral reference (relative mode).
  int64_t neutral_frame = 0;
  // Temporal smoothing in [0,1): 0 = none; higher follows the driver more slowly.
  double smoothing = 0.3;

  template <typename V>
  void Visit(V&& v) {
    v("relative", relative, "Transfer expression and pose relative to the neutral frame (--no-relative: absolute)");
    v("neutral_frame", neutral_frame, "Driver frame used as the neutral reference");
    v("smoothing", smoothing, "Temporal smoothing of the driver in [0,1) (0 = none)");
  }
  // Throws InvalidOptions (negative neutral frame, smoothing outside [0,1)).
  void Validate() const;
};

// What a driving video frame measures. Implemented with face analysis + morphable fitting.
struct FrameMeasurement {
  bool face_found = false;          // False: no face in this frame.
  ViewPose pose;                    // Head pose in degrees (zoom 1).
  std::vector<float> coefficients;  // Morphable-model expression coefficients.
};

// Analyses one driving frame (BGR8). Stateful implementations (trackers) get frames in
// order; Reset() is called before a seek. Throws like the face analysis it wraps.
class FrameAnalyzer {
 public:
  virtual ~FrameAnalyzer() = default;
  virtual FrameMeasurement Measure(const cv::Mat& bgr, RunContext& ctx) = 0;
  virtual void Reset() {}
};

// Combines measurements into driving samples: neutral subtraction and smoothing (the
// building block of DrivingVideo).
class DrivingTransfer {
 public:
  explicit DrivingTransfer(const DrivingOptions& options) : options_(options) {}
  // Sets the neutral reference (relative mode).
  void SetNeutral(const FrameMeasurement& neutral) { neutral_ = neutral; }
  const std::optional<FrameMeasurement>& Neutral() const { return neutral_; }
  // The sample for `m`; with `smooth` the previous output is blended in (sequential use). The
  // smoothing is per driver frame: when `frames_elapsed` driver frames passed since the previous
  // sample (live driving drops the frames the avatar cannot keep up with), the previous sample
  // weighs smoothing^frames_elapsed, so the lag in seconds does not grow on a slower machine.
  // Throws InvalidInput for frames_elapsed < 1.
  DrivingSample Apply(const FrameMeasurement& m, bool smooth, int64_t frames_elapsed = 1);
  // Forgets the smoothing history (after a seek).
  void ResetHistory() { previous_.reset(); }

 private:
  DrivingOptions options_;
  std::optional<FrameMeasurement> neutral_;
  std::optional<DrivingSample> previous_;
};

class Driver {
 public:
  virtual ~Driver() = default;
  // Frames per second of the driver.
  virtual double Fps() const = 0;
  // Number of frames (may be an estimate for some videos; Next() decides the end).
  virtual int64_t FrameCount() const = 0;
  // A media file whose audio belongs to the clip ("" = none).
  virtual std::string AudioSource() const { return {}; }
  // True if samples carry measured expressions/poses (false: timing only).
  virtual bool Measured() const { return true; }
  // Reads the next sample; false at the end.
  virtual bool Next(DrivingSample& sample, RunContext& ctx) = 0;
  // Throws InvalidInput (naming the driver's file) when it names an expression control that is
  // not in `known` (a source's ExpressionControls()); videos carry measured coefficients only.
  virtual void CheckControls(const std::vector<std::string>& known) const { (void)known; }
};

// Keyframes JSON:
//   {"fps": 25, "duration": 4.0,
//    "keys": [{"time": 0.0, "yaw": 0, "pitch": 0, "roll": 0, "zoom": 1,
//              "expression": {"smile": 0.0}}, ...]}
// Keys are sorted by time; values between keys are interpolated linearly, missing fields
// are 0 (zoom 1). "duration" defaults to the last key's time.
class KeyframeDriver : public Driver {
 public:
  struct Key {
    double time = 0.0;
    ViewPose pose;
    std::map<std::string, float> expression;
  };
  // Throws Io (unreadable) or InvalidInput (bad JSON, naming the field and the file).
  explicit KeyframeDriver(const std::filesystem::path& path);
  KeyframeDriver(std::vector<Key> keys, double fps, double duration);
  double Fps() const override { return fps_; }
  int64_t FrameCount() const override { return frames_; }
  bool Next(DrivingSample& sample, RunContext& ctx) override;
  // The interpolated sample at `time` seconds.
  DrivingSample At(double time) const;
  void CheckControls(const std::vector<std::string>& known) const override;

 private:
  void Init(double duration);
  std::filesystem::path path_;  // "" for keys made in code
  std::vector<Key> keys_;
  double fps_ = 25.0;
  int64_t frames_ = 0;
  int64_t next_ = 0;
};

// How many video frames DrivingVideo searches for one with a face: from the requested
// neutral frame on before it gives up, and back from a frame without a face after a jump
// (30 s at 25 fps).
inline constexpr int64_t kNeutralSearchFrames = 750;

// A driving video with random access: the sample of any frame index. The one video driver:
// the studio's preview (scrubbing and playback) and every export (VideoDriver) read frames
// through it, so both give the same pose and expression for the same frame.
// Rules:
//  - Neutral frame (relative mode): DrivingOptions::neutral_frame; past the end of the clip
//    it is refused (InvalidOptions). When that frame has no face, the first later frame with
//    a face is used and NeutralNote() says so; none within kNeutralSearchFrames is an
//    InvalidInput error.
//  - Missed face: a frame where the analyser finds no face holds the measurement of the
//    nearest earlier frame with a face (before the first one: the neutral frame, or in
//    absolute mode the first frame with a face from frame 0); the sample says
//    face_found = false. After a jump the earlier face is looked for within
//    kNeutralSearchFrames frames (so scrubbing stays quick); playback has no limit.
//  - Smoothing runs over consecutive indices (k, k+1, ...); any other index restarts it, so
//    a clip played from frame 0 gives exactly what an export gives.
// Each frame is measured once and kept (a pose and ~64 floats per frame, at most
// kMaxCachedFrames of them).
class DrivingVideo {
 public:
  static constexpr size_t kMaxCachedFrames = 20000;

  // With `analyzer` null the video gives timing and audio only (Measured() == false) and
  // samples are neutral. Throws like VideoReader, InvalidOptions (bad options, neutral frame
  // past the end), InvalidInput (no face found for the neutral frame), Cancelled.
  DrivingVideo(const std::filesystem::path& path, std::unique_ptr<FrameAnalyzer> analyzer,
               const DrivingOptions& options, RunContext& ctx);
  ~DrivingVideo();
  DrivingVideo(const DrivingVideo&) = delete;
  DrivingVideo& operator=(const DrivingVideo&) = delete;

  // Changes relative/absolute, the neutral frame or smoothing; throws like the constructor
  // (the previous options stay in force on an error).
  void SetOptions(const DrivingOptions& options, RunContext& ctx);
  const DrivingOptions& Options() const { return options_; }

  double Fps() const;
  int64_t FrameCount() const;
  const std::filesystem::path& Path() const;
  bool HasAudio() const;
  bool Measured() const { return analyzer_ != nullptr; }
  // The neutral frame in use (-1: absolute mode or not measured).
  int64_t NeutralFrame() const { return neutral_index_; }
  // "" or a sentence for the user saying which frame replaced a neutral frame without a face.
  const std::string& NeutralNote() const { return neutral_note_; }

  // The sample of frame `index` (and its picture in `frame_out`, BGR8, when not null).
  // Returns false when `index` is negative or past the end of the clip.
  bool At(int64_t index, DrivingSample& sample, RunContext& ctx, cv::Mat* frame_out = nullptr);

 private:
  struct Choice {
    int64_t index = -1;
    std::optional<FrameMeasurement> measurement;
    std::string note;
  };
  // Reads frame `index` and measures it (once; later calls reuse the measurement).
  const FrameMeasurement& Measure(int64_t index, RunContext& ctx, cv::Mat* frame_out, bool* read_ok);
  // The first frame with a face at or after `from` (within kNeutralSearchFrames).
  std::optional<int64_t> FirstFaceFrom(int64_t from, RunContext& ctx);
  // The nearest frame before `index` with a face, if any.
  std::optional<int64_t> LastFaceBefore(int64_t index, RunContext& ctx);
  Choice ChooseReference(const DrivingOptions& options, RunContext& ctx);

  std::unique_ptr<VideoReader> reader_;
  std::unique_ptr<FrameAnalyzer> analyzer_;
  DrivingOptions options_;
  DrivingTransfer transfer_;
  int64_t neutral_index_ = -1;
  std::string neutral_note_;
  std::optional<FrameMeasurement> fallback_;  // Held before the first frame with a face.
  std::map<int64_t, FrameMeasurement> measured_;
  int64_t last_index_ = -2;                    // Index of the previous At() call.
  int64_t last_measured_ = -2;                 // Index of the frame the analyser saw last.
  std::optional<FrameMeasurement> last_good_;  // Held measurement after last_index_.
};

// A driving video read front to back for an export: DrivingVideo::At(0), At(1), ...
class VideoDriver : public Driver {
 public:
  // Throws like DrivingVideo.
  VideoDriver(const std::filesystem::path& path, std::unique_ptr<FrameAnalyzer> analyzer, const DrivingOptions& options,
              RunContext& ctx);
  ~VideoDriver() override;
  double Fps() const override;
  int64_t FrameCount() const override;
  std::string AudioSource() const override;
  bool Measured() const override { return video_.Measured(); }
  bool Next(DrivingSample& sample, RunContext& ctx) override;
  const DrivingVideo& Video() const { return video_; }

 private:
  DrivingVideo video_;
  int64_t next_ = 0;
};

// ----------------------------------------------------------------------------- composition

// The camera of one frame: the portrait's own pose (`source_pose`), turned by the user's view
// offset (`user_view`: yaw/pitch/roll added, its zoom is the frame's zoom) and, when
// `driver_pose` is given, by the driver's head pose (relative to its neutral frame in
// relative mode). The one pose composition of the preview and every export.
ViewPose ComposeView(const ViewPose& source_pose, const ViewPose& user_view, const ViewPose* driver_pose);

// The expression of one frame: the user's named controls plus the driver's (clamped to
// [0,1]) and the driver's coefficients (none without a sample).
FrameExpression ComposeExpression(const FrameExpression& user, const DrivingSample* sample);

// The request of one frame: ComposeView (with the driver's pose when `follow_driver_pose`)
// and ComposeExpression, at `width` x `height`.
FrameRequest ComposeFrame(const ViewPose& source_pose, const ViewPose& user_view, const FrameExpression& user_expression,
                          const DrivingSample* sample, bool follow_driver_pose, int width, int height);

// Creates the analyser that turns driving frames into measurements, or null when this
// build has no face analysis / morphable model. `data_dir` as for DataPaths::Resolve.
using FrameAnalyzerFactory = std::function<std::unique_ptr<FrameAnalyzer>(RunContext& ctx)>;

// Opens `path` as a keyframe file (.json) or a driving video.
std::unique_ptr<Driver> OpenDriver(const std::filesystem::path& path, const FrameAnalyzerFactory& analyzers,
                                   const DrivingOptions& options, RunContext& ctx);

}  // namespace avatar
