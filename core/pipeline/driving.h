#pragma once
// Drivers: where an animation's per-frame expression and head pose come from. A driver is
// read front to back, one frame at a time, so an export of any length runs in constant
// memory. Two kinds:
//  - KeyframeDriver: a JSON file of timed keys (camera + named expression controls),
//    interpolated linearly;
//  - VideoDriver: a driving video; each frame is analysed by a FrameAnalyzer (face tracking +
//    morphable fit) into an expression vector and a head pose, transferred relative to a
//    chosen neutral frame or absolutely, and smoothed over time.

#include <cstdint>
#include <filesystem>
#include <functional>
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

// Combines measurements into driving samples: neutral subtraction and smoothing. Shared by
// the video driver (export) and the studio's driving panel (scrubbing).
class DrivingTransfer {
 public:
  explicit DrivingTransfer(const DrivingOptions& options) : options_(options) {}
  // Sets the neutral reference (relative mode).
  void SetNeutral(const FrameMeasurement& neutral) { neutral_ = neutral; }
  const std::optional<FrameMeasurement>& Neutral() const { return neutral_; }
  // The sample for `m`; with `smooth` the previous output is blended in (sequential use).
  DrivingSample Apply(const FrameMeasurement& m, bool smooth);
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

 private:
  void Init(double duration);
  std::vector<Key> keys_;
  double fps_ = 25.0;
  int64_t frames_ = 0;
  int64_t next_ = 0;
};

// A driving video read frame by frame. With `analyzer` null the driver gives timing and
// audio only (Measured() == false) and samples are neutral.
class VideoDriver : public Driver {
 public:
  // Throws like VideoReader; InvalidOptions when the neutral frame is past the end.
  VideoDriver(const std::filesystem::path& path, std::unique_ptr<FrameAnalyzer> analyzer, const DrivingOptions& options,
              RunContext& ctx);
  ~VideoDriver() override;
  double Fps() const override;
  int64_t FrameCount() const override;
  std::string AudioSource() const override;
  bool Measured() const override { return analyzer_ != nullptr; }
  bool Next(DrivingSample& sample, RunContext& ctx) override;
  // The last frame read (BGR8), for previews.
  const cv::Mat& LastFrame() const { return frame_; }

 private:
  std::unique_ptr<VideoReader> reader_;
  std::unique_ptr<FrameAnalyzer> analyzer_;
  DrivingTransfer transfer_;
  cv::Mat frame_;
  std::optional<FrameMeasurement> last_good_;
};

// Creates the analyser that turns driving frames into measurements, or null when this
// build has no face analysis / morphable model. `data_dir` as for DataPaths::Resolve.
using FrameAnalyzerFactory = std::function<std::unique_ptr<FrameAnalyzer>(RunContext& ctx)>;

// Opens `path` as a keyframe file (.json) or a driving video.
std::unique_ptr<Driver> OpenDriver(const std::filesystem::path& path, const FrameAnalyzerFactory& analyzers,
                                   const DrivingOptions& options, RunContext& ctx);

}  // namespace avatar
