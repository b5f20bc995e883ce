// `avatar-studio analyze IMAGE|VIDEO [--json] [--out-dir DIR]`: face analysis of a photo (all
// faces, the main face's aligned crop, matte, masks, overlay) or of a video (tracked landmarks
// and pose per frame, streamed so memory stays flat with the clip's length).

#include <cmath>
#include <cstdio>
#include <iostream>

#include <nlohmann/json.hpp>

#include "app/cli_util.h"
#include "app/cmd_bench.h"
#include "app/commands.h"
#include "core/io/video_io.h"
#include "core/tools/benchmarks.h"
#include "core/tools/media_analysis.h"
#include "core/util/error.h"
#include "core/util/threads.h"

namespace avatar::app {

struct AnalyzeOptions {
  // The photo or video (positional), the output folder, the frame limit and the face analysis
  // settings.
  MediaAnalysisOptions analysis;
  // Print one JSON report on stdout.
  bool json = false;
  // Video: include the 468 landmarks of every frame in the JSON report.
  bool landmarks = true;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("out_dir", analysis.out_dir, "Folder for the crop, matte, masks and landmark overlay", 'o');
    v("json", json, "Print one JSON report on stdout");
    v("landmarks", landmarks, "Video: include every frame's 468 landmarks in the JSON");
    v("max_frames", analysis.max_frames, "Video: analyse at most this many frames (0 = all)");
    analysis.face.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    analysis.Validate();
    common.Validate();
  }
};

namespace {

using nlohmann::json;

json BoxJson(const cv::Rect2f& b) { return {{"x", b.x}, {"y", b.y}, {"width", b.width}, {"height", b.height}}; }
json PoseJson(const face::HeadPose& p) { return {{"yaw", p.yaw}, {"pitch", p.pitch}, {"roll", p.roll}}; }
json PointsJson(const face::Landmarks& lm) {
  json a = json::array();
  for (const auto& p : lm.points) a.push_back({p.x, p.y, p.z});
  return a;
}

int AnalyzeImage(const AnalyzeOptions& o, RunContext& ctx) {
  const PhotoAnalysis a = AnalysePhoto(o.analysis, ctx);
  const face::AlignedPortrait& portrait = a.portrait;
  double norm = 0.0;
  for (float v : portrait.embedding) norm += static_cast<double>(v) * v;
  if (o.json) {
    json faces = json::array();
    for (const PhotoFace& f : a.faces) {
      json j = {{"box", BoxJson(f.detection.box)}, {"score", f.detection.score}, {"selected", f.selected},
                {"landmark_confidence", f.landmarks.confidence}, {"landmarks", PointsJson(f.landmarks)}};
      j["pose"] = f.pose ? PoseJson(*f.pose) : json(nullptr);
      faces.push_back(j);
    }
    json timings = json::object();
    for (const auto& s : a.timings) timings[s.stage] = s.ms;
    const auto& m = portrait.crop_from_image;
    json out = {{"input", o.analysis.input},
                {"kind", "image"},
                {"width", a.width},
                {"height", a.height},
                {"faces", faces},
                {"selected", a.selected},
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
    std::cout << "Found " << a.faces.size() << " face(s) in '" << o.analysis.input << "'; analysed face " << a.selected
              << " (yaw " << portrait.pose.yaw << ", pitch " << portrait.pose.pitch << ", roll " << portrait.pose.roll
              << " degrees).\n";
    if (!o.analysis.out_dir.empty())
      std::cout << "Wrote crop, matte, masks and overlay to '" << o.analysis.out_dir << "'.\n";
  }
  for (const auto& w : portrait.warnings) std::cerr << "analyze: warning: '" << o.analysis.input << "': " << w << "\n";
  return kExitOk;
}

int AnalyzeVideo(const AnalyzeOptions& o, RunContext& ctx) {
  // The report is streamed: header, one frame object at a time, footer.
  const auto on_start = [&](const VideoAnalysisInfo& info) {
    if (!o.json) return;
    std::cout << "{\"input\":" << json(o.analysis.input).dump() << ",\"kind\":\"video\",\"width\":" << info.width
              << ",\"height\":" << info.height << ",\"fps\":" << info.fps << ",\"frames\":[";
  };
  const auto on_frame = [&](const VideoFrameAnalysis& f) {
    if (!o.json) return;
    const face::TrackedFace& tf = f.face;
    json j = {{"index", f.index}, {"time", f.time}, {"found", tf.found}, {"confidence", tf.confidence},
              {"redetected", tf.redetected}};
    if (tf.found) {
      j["pose"] = PoseJson(tf.pose);
      if (o.landmarks) j["landmarks"] = PointsJson(tf.landmarks);
    }
    std::cout << (f.index ? "," : "") << j.dump();
  };
  const VideoAnalysis a = AnalyseVideo(o.analysis, ctx, on_start, on_frame);
  const int64_t n = a.frames;
  if (o.json) {
    json summary = {{"frame_count", n},
                    {"frames_with_face", a.frames_with_face},
                    {"redetections", a.redetections},
                    {"processing_fps", n / a.seconds},
                    {"timings_ms", {{"decode_per_frame", a.decode_ms_per_frame},
                                    {"track_per_frame", a.track_ms_per_frame},
                                    {"total", a.seconds * 1e3}}},
                    {"peak_rss_mb", PeakRssMb()}};
    std::cout << "]";
    for (auto it = summary.begin(); it != summary.end(); ++it) std::cout << "," << json(it.key()).dump() << ":" << it.value().dump();
    std::cout << "}\n";
  } else {
    std::cout << "Tracked a face in " << a.frames_with_face << " of " << n << " frames of '" << o.analysis.input
              << "' at " << n / a.seconds << " frames/s (peak memory " << PeakRssMb() << " MB).\n";
  }
  return kExitOk;
}

}  // namespace

int RunAnalyzeImpl(const AnalyzeOptions& options, RunContext& ctx) {
  options.Validate();
  return IsVideoPath(options.analysis.input) ? AnalyzeVideo(options, ctx) : AnalyzeImage(options, ctx);
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
    options.analysis.input = positionals[0];
    if (!options.common.data_dir.empty() && options.analysis.face.data_dir.empty())
      options.analysis.face.data_dir = options.common.data_dir;
    return RunAnalyzeImpl(options, ProcessContext());
  });
}

// `avatar-studio bench face`: per-stage times of AnalyzePortrait on two packaged photos and the
// tracking rate on the first frames of a clip, with this machine's GEMM rate measured in the
// same run (ratios stay comparable across noisy, shared machines). Flags: repetitions per
// photo, frames of the clip.
using BenchFaceOptions = BenchSubjectOptions<FaceBenchmarkOptions>;

int RunBenchFaceImpl(BenchFaceOptions o, RunContext& ctx) {
  o.Validate();
  o.bench.data_dir = o.common.data_dir;
  const FaceBenchmarkReport r = RunFaceBenchmark(o.bench, ctx);
  const double gemm = r.gemm_gflops;
  std::cout << "bench face: threads " << ConfiguredThreads() << ", GEMM baseline " << gemm << " GFLOP/s, model load "
            << r.model_load_ms << " ms\n";
  std::cout << "photo              stage        median ms   x GEMM-GFLOP (ms*GFLOP/s/1000)\n";
  for (const FaceBenchmarkStage& s : r.stages) {
    std::printf("%-18s %-12s %9.2f   %8.3f\n", s.photo.c_str(), s.stage.c_str(), s.median_ms,
                s.median_ms * gemm / 1000.0);
  }
  const double ms = r.track_ms_per_frame;
  std::printf("franck.mp4 tracking: %d frames, %.2f ms/frame (%.1f frames/s, decode included), x GEMM %.3f\n",
              r.tracked_frames, ms, 1000.0 / ms, ms * gemm / 1000.0);
  return kExitOk;
}

int RunBenchFace(const std::vector<std::string>& args) {
  return RunBenchSubject<BenchFaceOptions>(
      args, "face", "Times each face-analysis stage on packaged photos and the tracking rate on a clip.",
      RunBenchFaceImpl);
}

AVATAR_REGISTER_BENCH_SUBJECT("face", "face analysis stages (detect, mesh, crop, matte, embedding) and tracking", RunBenchFace);

AVATAR_REGISTER_COMMAND("analyze", "detect the face, landmarks, crop and matte of a photo or video", RunAnalyze);

}  // namespace avatar::app
