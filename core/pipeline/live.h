#pragma once
// Live driving: an avatar driven by a camera, frame by frame as the camera delivers them. Frames
// come from OpenCV's VideoCapture: a V4L2 device (/dev/videoN) or a video file paced at its own
// frame rate as if it were a camera (so that live driving can be tested and measured without
// one). A grabber thread keeps only the newest frame: when the avatar renders slower than the
// camera, frames are dropped, never queued, so the latency stays one frame's work. Each frame
// taken is tracked (detection only when tracking is lost), fitted, turned into a pose and an
// expression relative to the first frame with a face (the automatic neutral reference) with the
// driver's smoothing (core/pipeline/driving.h), composed as every other driver's frame
// (ComposeFrame) and rendered by the avatar's frame source.
// Bad input is told, never fatal: a frame without a face holds the last pose (and says so), a
// face that comes back resumes, a resolution change restarts the tracker, a camera that stops
// delivering ends the session with the reason.

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "core/pipeline/driving.h"
#include "core/pipeline/frame_source.h"
#include "core/util/run_context.h"

namespace cv {
class VideoCapture;
}

namespace avatar {

using LiveClock = std::chrono::steady_clock;

// The cameras this machine has: "/dev/videoN" paths that VideoCapture opens (V4L2). Empty when
// there are none.
std::vector<std::string> ListCameras();

// One frame as the camera delivered it.
struct CameraFrame {
  cv::Mat bgr;
  int64_t index = -1;             // frame number since the camera opened (gaps: dropped frames)
  LiveClock::time_point captured; // when the grabber received it
};

// Where live frames come from (CameraGrabber; tests script their own).
class LiveCamera {
 public:
  virtual ~LiveCamera() = default;
  // Waits up to `timeout_seconds` for a frame newer than the last one taken and moves it to
  // `frame`. False when none came (the camera ended, failed or stalled: see Ended(), Error()).
  virtual bool Take(CameraFrame* frame, double timeout_seconds) = 0;
  virtual bool Ended() const = 0;
  virtual std::string Error() const = 0;  // why the camera stopped, when it failed ("" otherwise)
  virtual int64_t Captured() const = 0;   // frames received
  virtual int64_t Dropped() const = 0;    // frames replaced by a newer one before they were taken
  virtual double Fps() const = 0;
};

// Reads a camera on its own thread, keeping only the newest frame.
class CameraGrabber : public LiveCamera {
 public:
  // `camera`: a device index ("0" = /dev/video0), a device path, or a video file (played at its
  // own frame rate, once). Throws InvalidInput when the device does not exist or does not open
  // (the message lists the cameras found, or says there are none) or the file is not a video.
  explicit CameraGrabber(const std::string& camera);
  ~CameraGrabber();
  CameraGrabber(const CameraGrabber&) = delete;
  CameraGrabber& operator=(const CameraGrabber&) = delete;

  bool Take(CameraFrame* frame, double timeout_seconds) override;
  bool Ended() const override;
  std::string Error() const override;
  int64_t Captured() const override;
  int64_t Dropped() const override;
  double Fps() const override { return fps_; }
  bool IsFile() const { return is_file_; }
  const std::string& Name() const { return name_; }

 private:
  void Loop();

  std::unique_ptr<cv::VideoCapture> capture_;
  std::string name_;
  bool is_file_ = false;
  double fps_ = 25.0;
  mutable std::mutex mutex_;
  std::condition_variable ready_;
  CameraFrame latest_;
  bool fresh_ = false;  // latest_ not yet taken
  bool ended_ = false;
  bool stop_ = false;
  std::string error_;
  int64_t captured_ = 0, dropped_ = 0;
  std::thread thread_;
};

// Live driving asks the network for a new expression on every 4th frame only (the photo's face
// follows every frame: DetailOptions::base_expression_every): 16-18 fps at 256 px on 2 cores
// where every frame gives 10-11 (docs/PERFORMANCE.md "Live driving"). `live`'s default and the
// studio's Live source.
inline constexpr int kLiveNetworkExpressionEvery = 4;

// The frame source live driving renders for `source` (the studio's and `live`'s one choice): a
// detail source becomes its ForLive(network_expression_every, keep_fusion) form (the network
// takes a new expression on every Nth frame; the geometric composite unless keep_fusion, which
// `live --fusion WEIGHTS` asks for); other sources are driven as they are. Throws
// InvalidOptions (N outside 1..100), InvalidInput (no source).
std::shared_ptr<const FrameSource> LiveFrameSource(std::shared_ptr<const FrameSource> source,
                                                   int network_expression_every = kLiveNetworkExpressionEvery,
                                                   bool keep_fusion = false);

struct LiveOptions {
  // Camera: device index, /dev/videoN or a video file (CameraGrabber).
  std::string camera = "0";
  // Output frame size.
  int width = 256;
  int height = 256;
  // Stop after this many seconds (0: when the camera ends, or on cancel).
  double seconds = 0.0;
  // A camera that delivers no frame for this long has stopped.
  double stall_seconds = 3.0;
  // Pose and expression transfer (relative to the automatic neutral frame) and smoothing.
  DrivingOptions driving;
  // Follow the driver's head pose (false: the expression only, the source's pose).
  bool follow_pose = true;

  template <typename V>
  void Visit(V&& v) {
    v("camera", camera, "Camera: a device index (0 = /dev/video0), a /dev/videoN path, or a video file played as a camera");
    v("width", width, "Output width");
    v("height", height, "Output height");
    v("seconds", seconds, "Stop after this many seconds (0: when the camera ends)");
    v("stall_seconds", stall_seconds, "A camera silent this long has stopped");
    v("follow_pose", follow_pose, "Follow the driver's head pose (--no-follow-pose: expression only)");
    driving.Visit(v);
  }
  // Throws InvalidOptions.
  void Validate() const;
};

// What happened to one delivered frame.
struct LiveFrameInfo {
  int64_t capture_index = -1;
  double latency_ms = 0.0;      // from capture to the rendered frame
  double analyse_ms = 0.0;      // face tracking and fit of the camera frame
  double render_ms = 0.0;       // the avatar's frame
  bool face_found = false;      // false: the last pose and expression are held
  DrivingSample sample;         // what drove the frame
  cv::Mat camera_bgr;           // the camera frame that drove it (shared, not copied)
  std::string note;             // a change the user should be told about ("" = none)
};

struct LiveStats {
  int64_t captured = 0, delivered = 0, dropped = 0, no_face = 0;
  double seconds = 0.0;          // wall time from the first frame taken to the last delivered
  double delivered_fps = 0.0;
  double camera_fps = 0.0;
  double latency_median_ms = 0.0, latency_p95_ms = 0.0;
  double analyse_median_ms = 0.0, render_median_ms = 0.0;
  std::string ended;             // why the session ended
  std::vector<std::string> notes;  // every note, in order
};

// Drives `source` from `camera` until it ends, `options.seconds` pass or ctx is cancelled;
// `on_frame` gets every rendered frame (in order) with its info. `analyzer` measures the camera
// frames (DrivingAnalyzers). Throws InvalidOptions, Cancelled; what the frame source throws.
LiveStats RunLive(const FrameSource& source, FrameAnalyzer& analyzer, LiveCamera& camera, const LiveOptions& options,
                  const std::function<void(const RenderedFrame&, const LiveFrameInfo&)>& on_frame, RunContext& ctx);

}  // namespace avatar
