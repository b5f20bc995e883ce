// Fuzz target "video": opening a driving video (core/io/video_io VideoReader: the checks in
// front of OpenCV's FFmpeg reader) and decoding its first frames, as DrivingVideo does.
// ffprobe (the audio probe, a separate process) is kept out: PATH is emptied for this target,
// which is how VideoReader behaves on a machine without ffprobe.
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include <cstdlib>

#include "core/io/video_io.h"
#include "core/util/error.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

std::string RunVideo(std::string_view input) {
  static const bool kNoPath = [] { return setenv("PATH", ProcessTempDir().c_str(), 1) == 0; }();
  (void)kNoPath;
  const std::filesystem::path file = FreshInputDir() / "clip.mp4";
  WriteFile(file, input);
  return AcceptAvatarErrors([&] {
    VideoReader reader(file);
    cv::Mat frame;
    for (int i = 0; i < 4 && reader.Read(frame); ++i) {
      if (frame.type() != CV_8UC3) throw std::logic_error("VideoReader returned a non-BGR8 frame");
    }
    reader.Seek(reader.Info().frame_count - 1);
    (void)reader.Read(frame);
  });
}

int VideoSeeds(const std::filesystem::path& dir) {
  int n = 0;
  struct Kind {
    const char* name;
    const char* fourcc;
  };
  for (const Kind& k : {Kind{"mp4v.mp4", "mp4v"}, Kind{"mjpg.avi", "MJPG"}, Kind{"h264.mp4", "avc1"}}) {
    const std::filesystem::path file = dir / k.name;
    cv::VideoWriter writer(file.string(), cv::CAP_FFMPEG,
                           cv::VideoWriter::fourcc(k.fourcc[0], k.fourcc[1], k.fourcc[2], k.fourcc[3]), 10.0,
                           cv::Size(32, 24));
    if (!writer.isOpened()) continue;
    for (int i = 0; i < 5; ++i) {
      cv::Mat frame(24, 32, CV_8UC3, cv::Scalar(40 * i, 255 - 40 * i, 128));
      cv::circle(frame, cv::Point(4 + 5 * i, 12), 4, cv::Scalar(255, 255, 255), -1);
      writer.write(frame);
    }
    writer.release();
    ++n;
  }
  return n;
}

AVATAR_FUZZ_TARGET("video", RunVideo, VideoSeeds);

}  // namespace
}  // namespace avatar::fuzz
