// `avatar-studio analyze IMAGE|VIDEO [--json] [--out-dir DIR]`: face analysis of a photo (all
// faces, the main face's aligned crop, matte, masks, overlay) or of a video (tracked landmarks
// and pose per frame, streamed so memory stays flat with the clip's length).

#include <filesystem>
#include <iostream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "app/cli_util.h"
#include "app/cmd_bench.h"
#include "app/commands.h"
#include "core/face/face_analyzer.h"
#include "core/face/face_geometry.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/util/error.h"
#include "core/io/data_paths.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

namespace avatar::app {

struct AnalyzeOptions {
  // The photo or video to analyse (positional).
  std::string input;
  // Folder for crop.png, crop_unmatted.png, matte.png, eye_mouth_mask.png, overlay.png ("" = none).
  std::string out_dir;
  // Print one JSON report on stdout.
  bool json = false;
  // Video: include the 468 landmarks of every frame in the JSON report.
  bool landmarks = true;
  // Video: analyse at most this many frames (0 = all).
  int max_frames = 0;
  // Face analysis settings.
  face::FaceAnalyzerOptions face;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("out_dir", out_dir, "Folder for the crop, matte, masks and landmark overlay", 'o');
    v("json", json, "Print one JSON report on stdout");
    v("landmarks", landmarks, "Video: include every frame's 468 landmarks in the JSON");
    v("max_frames", max_frames, "Video: analyse at most this many frames (0 = all)");
    face.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    AVATAR_CHECK_OPTION(!input.empty()) << "missing IMAGE or VIDEO: give the photo or clip to analyse";
    AVATAR_CHECK_OPTION(max_frames >= 0) << "--max-frames must be >= 0";
    face.Validate();
    common.Validate();
  }
};

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

json BoxJson(const cv::Rect2f& b) { return {{"x", b.x}, {"y", b.y}, {"width", b.width}, {"height", b.height}}; }
json PoseJson(const face::HeadPose& p) { return {{"yaw", p.yaw}, {"pitch", p.pitch}, {"roll", p.roll}}; }
json PointsJson(const face::Landmarks& lm) {
  json a = json::array();
  for (const auto& p : lm.points) a.push_back({p.x, p.y, p.z});
  return a;
}

void DrawLandmarks(cv::Mat& image, const face::Landmarks& lm, const cv::Scalar& colour) {
  const int r = std::max(1, image.cols / 600);
  for (const auto& p : lm.points) cv::circle(image, cv::Point(cvRound(p.x), cvRound(p.y)), r, colour, cv::FILLED);
}

cv::Mat Matte8(const cv::Mat& matte) {
  cv::Mat m8;
  matte.convertTo(m8, CV_8UC1, 255.0);
  return m8;
}

int AnalyzeImage(const AnalyzeOptions& o, RunContext& ctx) {
  Timer total;
  Timer t;
  const cv::Mat image = LoadImageBgr(o.input);
  const double load_ms = t.Milliseconds();
  t.Restart();
  const face::FaceAnalyzer analyzer(o.face);
  const double models_ms = t.Milliseconds();
  face::PortraitReport report;
  face::AlignedPortrait portrait;
  try {
    portrait = analyzer.AnalyzePortrait(image, ctx, &report);
  } catch (const InvalidInput& e) {
    throw InvalidInput("'" + o.input + "': " + e.what());
  }
  // Every face gets its landmarks and pose in the report (the selected one is already done).
  json faces = json::array();
  cv::Mat overlay = image.clone();
  t.Restart();
  for (size_t i = 0; i < report.faces.size(); ++i) {
    const auto& d = report.faces[i];
    const face::Landmarks lm = static_cast<int>(i) == report.selected ? report.image_landmarks : analyzer.Mesh(image, d);
    json f = {{"box", BoxJson(d.box)}, {"score", d.score}, {"selected", static_cast<int>(i) == report.selected},
              {"landmark_confidence", lm.confidence}, {"landmarks", PointsJson(lm)}};
    try {
      f["pose"] = PoseJson(face::HeadPoseFromLandmarks(lm));
    } catch (const InvalidInput&) {
      f["pose"] = nullptr;
    }
    faces.push_back(f);
    const cv::Scalar colour = static_cast<int>(i) == report.selected ? cv::Scalar(0, 255, 0) : cv::Scalar(0, 200, 255);
    cv::rectangle(overlay, d.box, colour, std::max(2, image.cols / 500));
    DrawLandmarks(overlay, lm, cv::Scalar(0, 0, 255));
  }
  const double other_faces_ms = t.Milliseconds();
  if (!o.out_dir.empty()) {
    const fs::path dir(o.out_dir);
    std::error_code ec;
    fs::create_directories(dir, ec);
    AVATAR_CHECK_AS(Io, !ec) << "cannot create the output folder " << dir << ": " << ec.message();
    SaveImage(dir / "crop.png", portrait.image);
    SaveImage(dir / "crop_unmatted.png", portrait.image_unmatted);
    SaveImage(dir / "matte.png", Matte8(portrait.matte));
    SaveImage(dir / "eye_mouth_mask.png", portrait.eye_mouth_mask);
    SaveImage(dir / "overlay.png", overlay);
  }
  double norm = 0.0;
  for (float v : portrait.embedding) norm += static_cast<double>(v) * v;
  if (o.json) {
    json timings = {{"load_image", load_ms}, {"load_models", models_ms}};
    for (const auto& s : report.timings) timings[s.stage] = s.ms;
    timings["other_faces_mesh"] = other_faces_ms;
    timings["total"] = total.Milliseconds();
    const auto& m = portrait.crop_from_image;
    json out = {{"input", o.input},
                {"kind", "image"},
                {"width", image.cols},
                {"height", image.rows},
                {"faces", faces},
                {"selected", report.selected},
                {"pose", PoseJson(portrait.pose)},
                {"crop", {{"size", portrait.image.cols},
                          {"crop_from_image", {{m(0, 0), m(0, 1), m(0, 2)}, {m(1, 0), m(1, 1), m(1, 2)}}}}},
                {"embedding_model", "fr_feature.onnx"},
                {"embedding_size", portrait.embedding.size()},
                {"embedding_norm", std::sqrt(norm)},
                {"embedding", portrait.embedding},
                {"warnings", portrait.warnings},
                {"timings_ms", timings},
                {"peak_rss_mb", PeakRssMb()}};
    std::cout << out.dump() << "\n";
  } else {
    std::cout << "Found " << report.faces.size() << " face(s) in '" << o.input << "'; analysed face " << report.selected
              << " (yaw " << portrait.pose.yaw << ", pitch " << portrait.pose.pitch << ", roll " << portrait.pose.roll
              << " degrees).\n";
    if (!o.out_dir.empty()) std::cout << "Wrote crop, matte, masks and overlay to '" << o.out_dir << "'.\n";
  }
  for (const auto& w : portrait.warnings) std::cerr << "analyze: warning: '" << o.input << "': " << w << "\n";
  return kExitOk;
}

int AnalyzeVideo(const AnalyzeOptions& o, RunContext& ctx) {
  Timer total;
  VideoReader reader(o.input);
  const VideoInfo info = reader.Info();
  const face::FaceAnalyzer analyzer(o.face);
  face::FaceTracker tracker(analyzer);
  const double fps = info.fps > 0 ? info.fps : 25.0;
  const int64_t planned = o.max_frames > 0 ? std::min<int64_t>(o.max_frames, std::max<int64_t>(info.frame_count, 1))
                                           : std::max<int64_t>(info.frame_count, 1);
  // The report is streamed: header, one frame object at a time, footer.
  if (o.json) {
    std::cout << "{\"input\":" << json(o.input).dump() << ",\"kind\":\"video\",\"width\":" << info.width
              << ",\"height\":" << info.height << ",\"fps\":" << fps << ",\"frames\":[";
  }
  cv::Mat frame;
  int64_t n = 0, found = 0, redetections = 0;
  double track_ms = 0.0, decode_ms = 0.0;
  cv::Mat first_overlay;
  Timer t;
  while ((o.max_frames == 0 || n < o.max_frames) && reader.Read(frame)) {
    decode_ms += t.Milliseconds();
    t.Restart();
    const face::TrackedFace tf = tracker.Track(frame, n / fps);
    track_ms += t.Milliseconds();
    found += tf.found;
    redetections += tf.redetected;
    if (o.json) {
      json f = {{"index", n}, {"time", n / fps}, {"found", tf.found}, {"confidence", tf.confidence},
                {"redetected", tf.redetected}};
      if (tf.found) {
        f["pose"] = PoseJson(tf.pose);
        if (o.landmarks) f["landmarks"] = PointsJson(tf.landmarks);
      }
      std::cout << (n ? "," : "") << f.dump();
    }
    if (n == 0 && !o.out_dir.empty()) {
      first_overlay = frame.clone();
      if (tf.found) DrawLandmarks(first_overlay, tf.landmarks, cv::Scalar(0, 0, 255));
    }
    ++n;
    ctx.Report("analyse video", static_cast<double>(n) / planned, "frame " + std::to_string(n));
    t.Restart();
  }
  AVATAR_CHECK_INPUT(n > 0) << "the video '" << o.input << "' has no readable frames; re-encode it (e.g. with ffmpeg)";
  if (!o.out_dir.empty()) {
    std::error_code ec;
    fs::create_directories(o.out_dir, ec);
    AVATAR_CHECK_AS(Io, !ec) << "cannot create the output folder " << o.out_dir << ": " << ec.message();
    SaveImage(fs::path(o.out_dir) / "overlay.png", first_overlay);
  }
  const double seconds = total.Seconds();
  if (o.json) {
    json summary = {{"frame_count", n},
                    {"frames_with_face", found},
                    {"redetections", redetections},
                    {"processing_fps", n / seconds},
                    {"timings_ms", {{"decode_per_frame", decode_ms / n}, {"track_per_frame", track_ms / n},
                                    {"total", seconds * 1e3}}},
                    {"peak_rss_mb", PeakRssMb()}};
    std::cout << "]";
    for (auto it = summary.begin(); it != summary.end(); ++it) std::cout << "," << json(it.key()).dump() << ":" << it.value().dump();
    std::cout << "}\n";
  } else {
    std::cout << "Tracked a face in " << found << " of " << n << " frames of '" << o.input << "' at " << n / seconds
              << " frames/s (peak memory " << PeakRssMb() << " MB).\n";
  }
  return kExitOk;
}

}  // namespace

int RunAnalyzeImpl(const AnalyzeOptions& options, RunContext& ctx) {
  options.Validate();
  return IsVideoPath(options.input) ? AnalyzeVideo(options, ctx) : AnalyzeImage(options, ctx);
}

int RunAnalyze(const std::vector<std::string>& args) {
  return GuardedRun("analyze", [&] {
    AnalyzeOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio analyze IMAGE|VIDEO [--json] [--out-dir DIR] [options]",
                      "Finds the faces of a photo and writes the main face's aligned 512x512 crop, its matte, "
                      "eye/mouth masks and a landmark overlay; for a video, tracks the face frame by frame "
                      "(smoothed landmarks and head pose). --json prints one report on stdout.",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.size() == 1) << "expected one IMAGE or VIDEO, got " << positionals.size() << " arguments";
    options.input = positionals[0];
    if (!options.common.data_dir.empty() && options.face.data_dir.empty()) options.face.data_dir = options.common.data_dir;
    return RunAnalyzeImpl(options, ProcessContext());
  });
}


// `avatar-studio bench face`: per-stage times of AnalyzePortrait on two packaged photos and the
// tracking rate on the first frames of a clip, with this machine's GEMM rate measured in the
// same run (ratios stay comparable across noisy, shared machines).
struct BenchFaceOptions {
  // Timed repetitions per photo (after one warm-up); medians are reported.
  int repeats = 5;
  // Frames of the clip tracked for the video rate.
  int frames = 100;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("repeats", repeats, "Timed repetitions per photo (median reported)");
    v("frames", frames, "Frames of franck.mp4 tracked for the video rate");
    common.Visit(v);
  }
  void Validate() const {
    AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 100) << "--repeats must be 1..100";
    AVATAR_CHECK_OPTION(frames >= 1) << "--frames must be >= 1";
    common.Validate();
  }
};

int RunBenchFaceImpl(const BenchFaceOptions& o, RunContext& ctx) {
  o.Validate();
  const DataPaths paths = DataPaths::Resolve(o.common.data_dir);
  const double gemm = MeasureGemmGflops();
  face::FaceAnalyzerOptions fo;
  fo.data_dir = o.common.data_dir;
  Timer load;
  const face::FaceAnalyzer analyzer(fo);
  const double load_ms = load.Milliseconds();
  std::cout << "bench face: threads " << ConfiguredThreads() << ", GEMM baseline " << gemm << " GFLOP/s, model load "
            << load_ms << " ms\n";
  std::cout << "photo              stage        median ms   x GEMM-GFLOP (ms*GFLOP/s/1000)\n";
  for (const char* name : {"grace_hopper.jpg", "sample1.jpg"}) {
    const cv::Mat image = LoadImageBgr(paths.Require(std::string("samples/") + name, "benchmark photo"));
    std::map<std::string, std::vector<double>> times;
    std::vector<std::string> order;
    for (int r = 0; r <= o.repeats; ++r) {
      face::PortraitReport report;
      analyzer.AnalyzePortrait(image, ctx, &report);
      if (r == 0) {
        for (const auto& s : report.timings) order.push_back(s.stage);
        continue;  // warm-up
      }
      double total = 0;
      for (const auto& s : report.timings) {
        times[s.stage].push_back(s.ms);
        total += s.ms;
      }
      times["total"].push_back(total);
    }
    order.push_back("total");
    for (const auto& stage : order) {
      auto v = times[stage];
      std::sort(v.begin(), v.end());
      const double med = v[v.size() / 2];
      std::printf("%-18s %-12s %9.2f   %8.3f\n", name, stage.c_str(), med, med * gemm / 1000.0);
    }
  }
  VideoReader reader(paths.Require("samples/franck.mp4", "benchmark clip"));
  face::FaceTracker tracker(analyzer);
  cv::Mat frame;
  int n = 0;
  Timer t;
  while (n < o.frames && reader.Read(frame)) {
    tracker.Track(frame, n / 25.0);
    ++n;
  }
  const double ms = t.Milliseconds() / std::max(1, n);
  std::printf("franck.mp4 tracking: %d frames, %.2f ms/frame (%.1f frames/s, decode included), x GEMM %.3f\n", n, ms,
              1000.0 / ms, ms * gemm / 1000.0);
  return kExitOk;
}

int RunBenchFace(const std::vector<std::string>& args) {
  return GuardedRun("bench face", [&] {
    BenchFaceOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio bench face [options]",
                      "Times each face-analysis stage on packaged photos and the tracking rate on a clip.",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.empty()) << "bench face takes no positional arguments";
    return RunBenchFaceImpl(options, ProcessContext());
  });
}

AVATAR_REGISTER_BENCH_SUBJECT("face", "face analysis stages (detect, mesh, crop, matte, embedding) and tracking", RunBenchFace);

AVATAR_REGISTER_COMMAND("analyze", "detect the face, landmarks, crop and matte of a photo or video", RunAnalyze);

}  // namespace avatar::app
