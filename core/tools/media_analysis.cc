#include "core/tools/media_analysis.h"

#include <algorithm>
#include <filesystem>

#include <opencv2/imgproc.hpp>

#include "core/face/face_geometry.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;

void DrawLandmarks(cv::Mat& image, const face::Landmarks& lm, const cv::Scalar& colour) {
  const int r = std::max(1, image.cols / 600);
  for (const auto& p : lm.points) cv::circle(image, cv::Point(cvRound(p.x), cvRound(p.y)), r, colour, cv::FILLED);
}

cv::Mat Matte8(const cv::Mat& matte) {
  cv::Mat m8;
  matte.convertTo(m8, CV_8UC1, 255.0);
  return m8;
}

void CreateOutputFolder(const fs::path& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  AVATAR_CHECK_AS(Io, !ec) << "cannot create the output folder " << dir << ": " << ec.message();
}

}  // namespace

void MediaAnalysisOptions::Validate() const {
  AVATAR_CHECK_OPTION(!input.empty()) << "missing IMAGE or VIDEO: give the photo or clip to analyse";
  AVATAR_CHECK_OPTION(max_frames >= 0) << "--max-frames must be >= 0";
  face.Validate();
}

PhotoAnalysis AnalysePhoto(const MediaAnalysisOptions& o, RunContext& ctx) {
  o.Validate();
  Timer total;
  Timer t;
  const cv::Mat image = LoadImageBgr(o.input);
  PhotoAnalysis out;
  out.width = image.cols;
  out.height = image.rows;
  out.timings.push_back({"load_image", t.Milliseconds()});
  t.Restart();
  const face::FaceAnalyzer analyzer(o.face);
  out.timings.push_back({"load_models", t.Milliseconds()});
  face::PortraitReport report;
  try {
    out.portrait = analyzer.AnalyzePortrait(image, ctx, &report);
  } catch (const InvalidInput& e) {
    throw InvalidInput("'" + o.input + "': " + e.what());
  }
  out.selected = report.selected;
  // Every face gets its landmarks and pose in the report (the selected one is already done).
  cv::Mat overlay = image.clone();
  t.Restart();
  for (size_t i = 0; i < report.faces.size(); ++i) {
    PhotoFace f;
    f.detection = report.faces[i];
    f.selected = static_cast<int>(i) == report.selected;
    f.landmarks = f.selected ? report.image_landmarks : analyzer.Mesh(image, f.detection);
    try {
      f.pose = face::HeadPoseFromLandmarks(f.landmarks);
    } catch (const InvalidInput&) {
      f.pose.reset();
    }
    const cv::Scalar colour = f.selected ? cv::Scalar(0, 255, 0) : cv::Scalar(0, 200, 255);
    cv::rectangle(overlay, f.detection.box, colour, std::max(2, image.cols / 500));
    DrawLandmarks(overlay, f.landmarks, cv::Scalar(0, 0, 255));
    out.faces.push_back(std::move(f));
  }
  const double other_faces_ms = t.Milliseconds();
  if (!o.out_dir.empty()) {
    const fs::path dir(o.out_dir);
    CreateOutputFolder(dir);
    SaveImage(dir / "crop.png", out.portrait.image);
    SaveImage(dir / "crop_unmatted.png", out.portrait.image_unmatted);
    SaveImage(dir / "matte.png", Matte8(out.portrait.matte));
    SaveImage(dir / "eye_mouth_mask.png", out.portrait.eye_mouth_mask);
    SaveImage(dir / "overlay.png", overlay);
  }
  for (const auto& s : report.timings) out.timings.push_back(s);
  out.timings.push_back({"other_faces_mesh", other_faces_ms});
  out.timings.push_back({"total", total.Milliseconds()});
  return out;
}

VideoAnalysis AnalyseVideo(const MediaAnalysisOptions& o, RunContext& ctx,
                           const std::function<void(const VideoAnalysisInfo&)>& on_start,
                           const std::function<void(const VideoFrameAnalysis&)>& on_frame) {
  o.Validate();
  Timer total;
  VideoReader reader(o.input);
  const VideoInfo info = reader.Info();
  const face::FaceAnalyzer analyzer(o.face);
  face::FaceTracker tracker(analyzer);
  VideoAnalysis out;
  out.info.width = info.width;
  out.info.height = info.height;
  out.info.fps = info.fps > 0 ? info.fps : 25.0;
  const double fps = out.info.fps;
  const int64_t planned = o.max_frames > 0 ? std::min<int64_t>(o.max_frames, std::max<int64_t>(info.frame_count, 1))
                                           : std::max<int64_t>(info.frame_count, 1);
  if (on_start) on_start(out.info);
  cv::Mat frame;
  int64_t n = 0;
  double track_ms = 0.0, decode_ms = 0.0;
  cv::Mat first_overlay;
  Timer t;
  while ((o.max_frames == 0 || n < o.max_frames) && reader.Read(frame)) {
    decode_ms += t.Milliseconds();
    t.Restart();
    VideoFrameAnalysis f;
    f.index = n;
    f.time = n / fps;
    f.face = tracker.Track(frame, f.time);
    track_ms += t.Milliseconds();
    out.frames_with_face += f.face.found;
    out.redetections += f.face.redetected;
    if (on_frame) on_frame(f);
    if (n == 0 && !o.out_dir.empty()) {
      first_overlay = frame.clone();
      if (f.face.found) DrawLandmarks(first_overlay, f.face.landmarks, cv::Scalar(0, 0, 255));
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
  out.frames = n;
  out.decode_ms_per_frame = decode_ms / n;
  out.track_ms_per_frame = track_ms / n;
  out.seconds = total.Seconds();
  return out;
}

}  // namespace avatar
