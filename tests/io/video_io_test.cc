#include "core/io/video_io.h"

#include <gtest/gtest.h>
#include <opencv2/videoio.hpp>

#include "common/temp_dir.h"
#include "core/io/atomic_file.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;

// Writes a small H.264 clip whose frame i has blue level 10*i.
void WriteClip(const std::filesystem::path& path, int frames, double fps = 25.0) {
  cv::VideoWriter writer(path.string(), cv::CAP_FFMPEG, cv::VideoWriter::fourcc('a', 'v', 'c', '1'), fps,
                         cv::Size(64, 48));
  ASSERT_TRUE(writer.isOpened());
  for (int i = 0; i < frames; ++i) writer.write(cv::Mat(48, 64, CV_8UC3, cv::Scalar(10 * i, 128, 0)));
}

TEST(VideoIo, ReadsEveryFrameInOrder) {
  TempDir dir;
  WriteClip(dir / "c.mp4", 12);
  VideoReader reader(dir / "c.mp4");
  EXPECT_EQ(reader.Info().width, 64);
  EXPECT_EQ(reader.Info().height, 48);
  EXPECT_NEAR(reader.Info().fps, 25.0, 1e-6);
  EXPECT_EQ(reader.Info().frame_count, 12);
  EXPECT_FALSE(reader.Info().has_audio);
  cv::Mat frame;
  int n = 0;
  while (reader.Read(frame)) {
    ASSERT_EQ(frame.type(), CV_8UC3);
    EXPECT_NEAR(cv::mean(frame)[0], 10.0 * n, 4.0) << "frame " << n;  // Lossy codec: a few levels.
    ++n;
  }
  EXPECT_EQ(n, 12);
  reader.Seek(5);
  ASSERT_TRUE(reader.Read(frame));
  EXPECT_NEAR(cv::mean(frame)[0], 50.0, 4.0);
}

TEST(VideoIo, BadVideosGiveClearErrors) {
  TempDir dir;
  EXPECT_THROW(VideoReader(dir / "none.mp4"), Io);
  WriteBytesAtomically(dir / "zero.mp4", "");
  EXPECT_THROW(VideoReader(dir / "zero.mp4"), InvalidInput);
  WriteBytesAtomically(dir / "junk.mp4", std::string(4096, 'x'));
  try {
    VideoReader reader(dir / "junk.mp4");
    FAIL() << "junk opened as a video";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("junk.mp4"), std::string::npos) << e.what();
  }
  // A container with a video stream but no frames.
  ASSERT_EQ(RunProgram("ffmpeg", {"-nostdin", "-v", "error", "-f", "lavfi", "-i", "color=c=black:s=32x32:d=1", "-frames:v",
                                  "0", "-c:v", "libx264", (dir / "empty.mp4").string()}),
            0);
  EXPECT_THROW(VideoReader(dir / "empty.mp4"), InvalidInput);
}

TEST(VideoIo, MuxAudioKeepsVideoAndAddsAudio) {
  TempDir dir;
  WriteClip(dir / "v.mp4", 25);
  ASSERT_EQ(RunProgram("ffmpeg", {"-nostdin", "-v", "error", "-f", "lavfi", "-i", "sine=frequency=440:duration=2",
                                  (dir / "a.m4a").string()}),
            0);
  EXPECT_TRUE(ProbeHasAudio(dir / "a.m4a"));
  MuxAudio(dir / "v.mp4", dir / "a.m4a", dir / "out.mp4");
  EXPECT_TRUE(ProbeHasAudio(dir / "out.mp4"));
  VideoReader reader(dir / "out.mp4");
  EXPECT_EQ(reader.Info().frame_count, 25);
  // A source without audio fails cleanly and leaves no output or temporary file.
  EXPECT_THROW(MuxAudio(dir / "v.mp4", dir / "v.mp4", dir / "bad.mp4"), Io);
  for (const auto& name : dir.List()) EXPECT_EQ(name.find("bad"), std::string::npos) << name;
}

TEST(VideoIo, RecognisesVideoExtensions) {
  EXPECT_TRUE(IsVideoPath("a/B.MP4"));
  EXPECT_TRUE(IsVideoPath("x.webm"));
  EXPECT_FALSE(IsVideoPath("x.jpg"));
}

}  // namespace
}  // namespace avatar
