#include "core/pipeline/live.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <sstream>

#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "core/io/video_io.h"
#include "core/pipeline/detail_source.h"
#include "core/util/error.h"

namespace avatar {
namespace {

bool AllDigits(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](unsigned char c) { return std::isdigit(c) != 0; });
}

std::string CamerasFound() {
  const std::vector<std::string> found = ListCameras();
  if (found.empty()) return "this machine has no camera";
  std::string s = "cameras found: ";
  for (size_t i = 0; i < found.size(); ++i) s += (i ? ", " : "") + found[i];
  return s;
}

double Seconds(LiveClock::duration d) { return std::chrono::duration<double>(d).count(); }

}  // namespace

std::vector<std::string> ListCameras() {
  std::vector<std::string> out;
  std::error_code ec;
  for (int i = 0; i < 64; ++i) {
    const std::string path = "/dev/video" + std::to_string(i);
    if (!std::filesystem::exists(path, ec)) continue;
    cv::VideoCapture probe(i, cv::CAP_V4L2);
    if (probe.isOpened()) out.push_back(path);
  }
  return out;
}

CameraGrabber::CameraGrabber(const std::string& camera) : capture_(std::make_unique<cv::VideoCapture>()) {
  AVATAR_CHECK_INPUT(!camera.empty()) << "no camera given: name a device index (0), /dev/videoN or a video file";
  std::string device = camera;
  if (AllDigits(camera)) device = "/dev/video" + camera;
  if (device.rfind("/dev/video", 0) == 0) {
    name_ = device;
    std::error_code ec;
    AVATAR_CHECK_INPUT(std::filesystem::exists(device, ec))
        << "no camera " << device << " (" << CamerasFound() << "); give --camera N of a connected camera, or a "
        << "video file to play as a camera";
    const std::string digits = device.substr(std::string("/dev/video").size());
    const bool opened = AllDigits(digits) ? capture_->open(std::stoi(digits), cv::CAP_V4L2)
                                          : capture_->open(device, cv::CAP_V4L2);
    AVATAR_CHECK_INPUT(opened) << "the camera " << device << " does not open (busy, or no permission: is the user in "
                               << "the 'video' group?); " << CamerasFound();
    const double fps = capture_->get(cv::CAP_PROP_FPS);
    if (std::isfinite(fps) && fps > 1.0 && fps <= 240.0) fps_ = fps;
  } else {
    name_ = camera;
    is_file_ = true;
    std::error_code ec;
    AVATAR_CHECK_INPUT(std::filesystem::is_regular_file(camera, ec))
        << "'" << camera << "' is neither a camera (a device index such as 0, or /dev/videoN) nor a video file";
    const VideoInfo info = VideoReader(camera).Info();  // throws naming the file when it is not a video
    AVATAR_CHECK_INPUT(capture_->open(camera)) << "'" << camera << "': the video does not open";
    if (std::isfinite(info.fps) && info.fps > 1.0 && info.fps <= 240.0) fps_ = info.fps;
  }
  thread_ = std::thread([this] { Loop(); });
}

CameraGrabber::~CameraGrabber() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  ready_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void CameraGrabber::Loop() {
  const LiveClock::time_point start = LiveClock::now();
  int64_t index = 0;
  for (;;) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stop_) return;
    }
    if (is_file_) {
      // A file plays as a camera: frame k is delivered k / fps after the first.
      std::this_thread::sleep_until(start + std::chrono::duration_cast<LiveClock::duration>(
                                                std::chrono::duration<double>(static_cast<double>(index) / fps_)));
    }
    cv::Mat bgr;
    bool ok = false;
    std::string error;
    try {
      ok = capture_->read(bgr) && !bgr.empty();
    } catch (const cv::Exception& e) {
      error = std::string("the camera failed: ") + e.what();
    }
    std::lock_guard<std::mutex> lock(mutex_);
    if (!ok) {
      ended_ = true;
      if (!error.empty()) error_ = error;
      else if (!is_file_) error_ = "the camera stopped delivering frames";
      ready_.notify_all();
      return;
    }
    if (bgr.channels() == 1) cv::cvtColor(bgr, bgr, cv::COLOR_GRAY2BGR);
    if (fresh_) ++dropped_;  // newest frame wins
    latest_.bgr = std::move(bgr);
    latest_.index = index++;
    latest_.captured = LiveClock::now();
    fresh_ = true;
    ++captured_;
    ready_.notify_all();
  }
}

bool CameraGrabber::Take(CameraFrame* frame, double timeout_seconds) {
  std::unique_lock<std::mutex> lock(mutex_);
  const bool got = ready_.wait_for(lock, std::chrono::duration<double>(std::max(0.0, timeout_seconds)),
                                   [this] { return fresh_ || ended_ || stop_; });
  if (!got || !fresh_) return false;
  *frame = std::move(latest_);
  latest_ = CameraFrame{};
  fresh_ = false;
  return true;
}

bool CameraGrabber::Ended() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return ended_ && !fresh_;
}
std::string CameraGrabber::Error() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return error_;
}
int64_t CameraGrabber::Captured() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return captured_;
}
int64_t CameraGrabber::Dropped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return dropped_;
}

void LiveOptions::Validate() const {
  AVATAR_CHECK_OPTION(!camera.empty()) << "--camera must name a device index, /dev/videoN or a video file";
  AVATAR_CHECK_OPTION(width >= 16 && height >= 16 && width <= 2048 && height <= 2048)
      << "the live frame size must be within 16..2048, got " << width << "x" << height;
  AVATAR_CHECK_OPTION(std::isfinite(seconds) && seconds >= 0.0) << "--seconds must be >= 0, got " << seconds;
  AVATAR_CHECK_OPTION(std::isfinite(stall_seconds) && stall_seconds > 0.0 && stall_seconds <= 60.0)
      << "--stall-seconds must be in (0, 60], got " << stall_seconds;
  driving.Validate();
}

LiveStats RunLive(const FrameSource& source, FrameAnalyzer& analyzer, LiveCamera& camera, const LiveOptions& options,
                  const std::function<void(const RenderedFrame&, const LiveFrameInfo&)>& on_frame, RunContext& ctx) {
  options.Validate();
  LiveStats stats;
  stats.camera_fps = camera.Fps();
  DrivingOptions transfer_options = options.driving;
  DrivingTransfer transfer(transfer_options);
  DrivingSample last;  // held while no face is seen (the source's own pose and expression at first)
  last.face_found = false;
  bool have_sample = false, face_was_found = true;
  int64_t last_sampled_index = -1;  // camera index of the frame that gave `last`
  cv::Size frame_size;
  std::vector<double> latencies, analyse_ms, render_ms;
  LiveClock::time_point first{}, last_delivered{};
  auto note = [&](LiveFrameInfo& info, const std::string& text) {
    info.note = info.note.empty() ? text : info.note + " " + text;
    stats.notes.push_back(text);
  };
  for (;;) {
    ctx.ThrowIfCancelled();
    if (options.seconds > 0.0 && stats.delivered > 0 && Seconds(LiveClock::now() - first) >= options.seconds) {
      std::ostringstream reason;
      reason << "the " << options.seconds << " s asked for have passed";
      stats.ended = reason.str();
      break;
    }
    CameraFrame frame;
    if (!camera.Take(&frame, options.stall_seconds)) {
      if (camera.Ended()) {
        stats.ended = camera.Error().empty() ? "the video ended" : camera.Error();
      } else {
        std::ostringstream reason;
        reason << "the camera delivered no frame for " << options.stall_seconds << " s";
        stats.ended = reason.str();
      }
      break;
    }
    if (stats.delivered == 0 && first == LiveClock::time_point{}) first = frame.captured;
    LiveFrameInfo info;
    info.capture_index = frame.index;
    info.camera_bgr = frame.bgr;
    if (frame_size != cv::Size() && frame.bgr.size() != frame_size) {
      analyzer.Reset();  // the tracker's box belongs to the old resolution
      note(info, "The camera changed its resolution from " + std::to_string(frame_size.width) + "x" +
                     std::to_string(frame_size.height) + " to " + std::to_string(frame.bgr.cols) + "x" +
                     std::to_string(frame.bgr.rows) + "; tracking restarted.");
    }
    frame_size = frame.bgr.size();
    const LiveClock::time_point analyse_start = LiveClock::now();
    const FrameMeasurement m = analyzer.Measure(frame.bgr, ctx);
    info.analyse_ms = 1000.0 * Seconds(LiveClock::now() - analyse_start);
    if (m.face_found) {
      if (options.driving.relative && !transfer.Neutral().has_value()) {
        transfer.SetNeutral(m);  // the automatic neutral reference: the first face seen
        note(info, "Neutral reference: camera frame " + std::to_string(frame.index) + ".");
      }
      // Smoothing per camera frame: the frames dropped since the last sample count.
      const int64_t elapsed = last_sampled_index >= 0 ? std::max<int64_t>(1, frame.index - last_sampled_index) : 1;
      last = transfer.Apply(m, have_sample, elapsed);
      last_sampled_index = frame.index;
      have_sample = true;
      if (!face_was_found && stats.delivered > 0) note(info, "The face is back.");
      face_was_found = true;
    } else {
      ++stats.no_face;
      if (face_was_found) {
        note(info, have_sample ? "No face in the camera frame: holding the last pose and expression."
                               : "No face in the camera frame yet: showing the portrait's own pose.");
      }
      face_was_found = false;
    }
    info.face_found = m.face_found;
    info.sample = last;
    info.sample.face_found = m.face_found;
    const FrameRequest request = ComposeFrame(source.SourcePose(), ViewPose{}, FrameExpression{},
                                              have_sample ? &last : nullptr, options.follow_pose, options.width,
                                              options.height);
    const LiveClock::time_point render_start = LiveClock::now();
    const RenderedFrame rendered = source.Render(request, ctx);
    const LiveClock::time_point done = LiveClock::now();
    info.render_ms = 1000.0 * Seconds(done - render_start);
    analyse_ms.push_back(info.analyse_ms);
    render_ms.push_back(info.render_ms);
    info.latency_ms = 1000.0 * Seconds(done - frame.captured);
    latencies.push_back(info.latency_ms);
    ++stats.delivered;
    last_delivered = done;
    on_frame(rendered, info);
  }
  stats.captured = camera.Captured();
  stats.dropped = camera.Dropped();
  if (stats.delivered > 0) {
    stats.seconds = Seconds(last_delivered - first);
    stats.delivered_fps = stats.seconds > 0.0 ? static_cast<double>(stats.delivered - 1) / stats.seconds : 0.0;
    std::vector<double> sorted = latencies;
    std::sort(sorted.begin(), sorted.end());
    stats.latency_median_ms = sorted[sorted.size() / 2];
    auto median = [](std::vector<double> v) {
      std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
      return v[v.size() / 2];
    };
    stats.analyse_median_ms = median(analyse_ms);
    stats.render_median_ms = median(render_ms);
    stats.latency_p95_ms = sorted[std::min(sorted.size() - 1, static_cast<size_t>(std::ceil(0.95 * sorted.size())) - 1)];
  }
  return stats;
}

std::shared_ptr<const FrameSource> LiveFrameSource(std::shared_ptr<const FrameSource> source,
                                                   int network_expression_every, bool keep_fusion) {
  AVATAR_CHECK_INPUT(source != nullptr) << "live driving needs a frame source";
  if (const auto* detail = dynamic_cast<const DetailFrameSource*>(source.get()))
    return detail->ForLive(network_expression_every, keep_fusion);
  return source;
}

}  // namespace avatar
