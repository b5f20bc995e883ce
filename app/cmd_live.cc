// avatar-studio live: an avatar driven live by a camera (or a video file played as one).
#include <algorithm>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "app/cli_util.h"
#include "app/commands.h"
#include "core/pipeline/export.h"
#include "core/pipeline/live.h"
#include "core/pipeline/studio_backend.h"
#include "core/tools/mouth_follow.h"
#include "core/util/error.h"
#include "core/util/progress_line.h"

namespace avatar::app {

struct LiveCommandOptions {
  std::string input;   // portrait photo or FILE.avatar
  std::string output;  // recording (.mp4), "" = none
  int size = 256;
  bool mouth_follow = false;  // measure how the output's mouth follows the driver's, after the run
  LiveOptions live;
  BackendOptions backend;
  CommonOptions common;

  LiveCommandOptions() { backend.network_expression_every = kLiveNetworkExpressionEvery; }

  template <typename V>
  void Visit(V&& v) {
    v("output", output, "Record the driven avatar to this MP4 (no audio)", 'o');
    v("size", size, "Side of the output frames");
    v("mouth_follow", mouth_follow,
      "After the run, measure how the avatar's mouth followed the driver's (face analysis of both, correlation)");
    live.Visit(v);
    backend.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    AVATAR_CHECK_OPTION(!input.empty()) << "missing PORTRAIT or FILE.avatar: give the avatar to drive";
    AVATAR_CHECK_OPTION(size >= 16 && size <= 2048) << "--size must be within 16..2048, got " << size;
    LiveOptions l = live;
    l.width = l.height = size;
    l.Validate();
    backend.Validate();
    common.Validate();
  }
};

int RunLiveImpl(LiveCommandOptions options, RunContext& ctx) {
  options.Validate();
  options.live.width = options.live.height = options.size;
  options.backend.data_dir = options.common.data_dir;
  // The camera first: no camera is the most likely mistake, and it costs nothing to find out.
  CameraGrabber camera(options.live.camera);
  // The geometric composite unless --fusion names a net (LiveFrameSource).
  const std::shared_ptr<const FrameSource> source =
      LiveFrameSource(OpenAvatarSource(options.input, options.backend, ctx), options.backend.network_expression_every,
                      /*keep_fusion=*/!options.backend.fusion.empty());
  for (const std::string& w : source->Warnings()) std::cerr << "warning: " << w << "\n";
  std::unique_ptr<FrameAnalyzer> analyzer = DrivingAnalyzers(options.backend)(ctx);
  AVATAR_CHECK_INPUT(analyzer != nullptr) << "this build cannot analyse camera frames (no face analysis)";
  std::unique_ptr<FrameSink> sink;
  if (!options.output.empty()) {
    ExportOptions e;
    e.output = options.output;
    e.format = "mp4";
    e.fps = camera.Fps();
    sink = OpenFrameSink(e, options.size, options.size);
  }
  std::cerr << "live: " << source->Label() << ", driven by " << (camera.IsFile() ? "the video " : "the camera ")
            << camera.Name() << " at " << camera.Fps() << " fps; Ctrl+C stops.\n";
  ProgressLine progress = ProgressLine::ForStderr();
  int64_t last_index = -1;
  ExportFrame held;
  std::vector<cv::Mat> driver_frames, output_frames;  // --mouth-follow: every delivered pair
  const auto start = LiveClock::now();
  const LiveStats stats = RunLive(
      *source, *analyzer, camera, options.live,
      [&](const RenderedFrame& frame, const LiveFrameInfo& info) {
        if (!info.note.empty()) {
          progress.Finish();
          std::cerr << "live: " << info.note << "\n";
        }
        if (sink) {
          // Real time: a frame stands until the next delivered one (the dropped frames' time).
          for (int64_t k = last_index + 1; last_index >= 0 && k < info.capture_index; ++k) sink->Write(held);
          held.bgr = frame.bgr;
          held.alpha = cv::Mat();
          sink->Write(held);
        }
        last_index = info.capture_index;
        if (options.mouth_follow) {
          driver_frames.push_back(info.camera_bgr);
          output_frames.push_back(frame.bgr);
        }
        std::ostringstream line;
        const double t = std::chrono::duration<double>(LiveClock::now() - start).count();
        line << "live: camera frame " << info.capture_index << ", " << std::fixed << std::setprecision(0)
             << info.latency_ms << " ms from capture" << (info.face_found ? "" : ", no face") << ", " << std::setprecision(1)
             << t << " s";
        progress.Update(line.str());
      },
      ctx);
  progress.Finish();
  if (sink) sink->Finish();
  std::cout << "Live: " << stats.delivered << " frames delivered of " << stats.captured << " captured (" << stats.dropped
            << " dropped, newest frame wins; " << stats.no_face << " without a face) in " << std::fixed
            << std::setprecision(1) << stats.seconds << " s: " << std::setprecision(2) << stats.delivered_fps
            << " fps delivered (camera " << stats.camera_fps << " fps), latency capture to frame median "
            << std::setprecision(0) << stats.latency_median_ms << " ms, p95 " << stats.latency_p95_ms << " ms (median "
            << stats.analyse_median_ms << " ms tracking and fit, " << stats.render_median_ms << " ms rendering). Ended: "
            << stats.ended << ". Rendered by " << source->Label();
  if (sink) std::cout << "; recorded to '" << options.output << "' (" << sink->FramesWritten() << " frames)";
  std::cout << ".\n";
  if (options.mouth_follow) {
    std::cerr << "live: measuring the mouth in " << driver_frames.size() << " driver and avatar frames...\n";
    face::FaceMetricsOptions fo;
    fo.data_dir = options.common.data_dir;
    fo.expression = false;
    const face::FaceMetrics faces(fo);
    const MouthFollow m = MeasureMouthFollow(driver_frames, output_frames, faces, ctx);
    auto range = [](const std::vector<double>& v) {
      if (v.empty()) return std::string("-");
      const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
      std::ostringstream s;
      s << std::fixed << std::setprecision(3) << *lo << ".." << *hi;
      return s.str();
    };
    std::cout << "Mouth follow: correlation of the mouth opening, driver vs avatar, " << std::fixed
              << std::setprecision(3) << m.correlation << " over " << m.measured << " of " << m.pairs
              << " frames with a face in both (driver " << range(m.driver) << ", avatar " << range(m.output) << ").\n";
  }
  return kExitOk;
}

int RunLive(const std::vector<std::string>& args) {
  return GuardedRun("live", [&] {
    LiveCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio live PORTRAIT|FILE.avatar [--camera N|/dev/videoN|VIDEO] [-o out.mp4]",
                      "Drives an avatar live from a camera: head pose and expression follow the face in front of "
                      "it (relative to the first frame with a face). A video file plays as a camera at its own "
                      "frame rate. Frames the avatar cannot keep up with are dropped, never queued. With the "
                      "head detail, live frames are the geometric composite unless --fusion names a fusion net.",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.size() <= 1)
        << "expected one PORTRAIT or FILE.avatar, got " << positionals.size() << " arguments";
    if (!positionals.empty()) options.input = positionals[0];
    return RunLiveImpl(options, ProcessContext());
  });
}

AVATAR_REGISTER_COMMAND("live", "drive an avatar live from a camera (or a video played as one)", RunLive);

}  // namespace avatar::app
