#include "core/pipeline/export.h"

#include <gtest/gtest.h>

#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/temp_dir.h"
#include "core/io/video_io.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;

// A synthetic test pattern: a disc with a soft edge moving right by one pixel per frame.
// (Exporter input only; it stands for rendered frames in these tests.)
bool Disc(int64_t index, ExportFrame& f, int w = 64, int h = 48) {
  f.bgr = cv::Mat(h, w, CV_8UC3, cv::Scalar(20, 40, 60));
  f.alpha = cv::Mat(h, w, CV_8UC1, cv::Scalar(0));
  cv::circle(f.alpha, cv::Point(20 + static_cast<int>(index), h / 2), 12, cv::Scalar(255), cv::FILLED, cv::LINE_AA);
  cv::GaussianBlur(f.alpha, f.alpha, cv::Size(5, 5), 1.5);
  f.bgr.setTo(cv::Scalar(200, 180, 160), f.alpha > 128);
  return true;
}

FrameProducer Frames(int64_t count) {
  return [count](int64_t i, ExportFrame& f) { return i < count && Disc(i, f); };
}

TEST(Export, Mp4HasEveryFrameAtTheRequestedRate) {
  TempDir dir;
  ExportOptions o;
  o.output = (dir / "clip.mp4").string();
  o.fps = 12.5;
  RunContext ctx;
  const ExportStats stats = ExportFrames(Frames(30), 30, 64, 48, o, ctx);
  EXPECT_EQ(stats.frames, 30);
  VideoReader reader(dir / "clip.mp4");
  EXPECT_EQ(reader.Info().frame_count, 30);
  EXPECT_NEAR(reader.Info().fps, 12.5, 1e-3);
  EXPECT_FALSE(reader.Info().has_audio);
  EXPECT_EQ(dir.List(), std::vector<std::string>{"clip.mp4"});
  EXPECT_DOUBLE_EQ(ctx.Last().fraction, 1.0);
}

TEST(Export, Mp4KeepsTheDriversAudio) {
  TempDir dir;
  ASSERT_EQ(RunProgram("ffmpeg", {"-nostdin", "-v", "error", "-f", "lavfi", "-i", "sine=frequency=300:duration=3",
                                  (dir / "voice.m4a").string()}),
            0);
  ExportOptions o;
  o.output = (dir / "talk.mp4").string();
  o.audio_from = (dir / "voice.m4a").string();
  RunContext ctx;
  ExportFrames(Frames(25), 25, 64, 48, o, ctx);
  EXPECT_TRUE(ProbeHasAudio(dir / "talk.mp4"));
  EXPECT_EQ(VideoReader(dir / "talk.mp4").Info().frame_count, 25);
  EXPECT_EQ(dir.List().size(), 2u);  // voice.m4a and talk.mp4 only.
}

TEST(Export, PngSequenceHasTrueVaryingAlpha) {
  TempDir dir;
  ExportOptions o;
  o.output = (dir / "frames").string();
  RunContext ctx;
  EXPECT_EQ(o.ResolvedFormat(), "png");
  ExportFrames(Frames(3), 3, 64, 48, o, ctx);
  const cv::Mat png = cv::imread((dir / "frames" / "frame_000002.png").string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(png.type(), CV_8UC4);
  std::vector<cv::Mat> ch;
  cv::split(png, ch);
  ExportFrame expected;
  Disc(2, expected);
  EXPECT_EQ(cv::norm(ch[3], expected.alpha, cv::NORM_INF), 0.0);
  const int partial = cv::countNonZero((ch[3] > 0) & (ch[3] < 255));
  EXPECT_GT(partial, 20) << "the edge of the disc must have partial alpha";
  EXPECT_TRUE(std::filesystem::exists(dir / "frames" / "frame_000000.png"));
  EXPECT_FALSE(std::filesystem::exists(dir / "frames" / "frame_000003.png"));
}

TEST(Export, PngSequenceReplacesAnEarlierExport) {
  TempDir dir;
  ExportOptions o;
  o.output = (dir / "frames").string();
  RunContext ctx;
  ExportFrames(Frames(5), 5, 64, 48, o, ctx);
  ExportFrames(Frames(2), 2, 64, 48, o, ctx);
  EXPECT_FALSE(std::filesystem::exists(dir / "frames" / "frame_000004.png"));
  EXPECT_EQ(dir.List(), std::vector<std::string>{"frames"});
}

TEST(Export, PngFolderWorksWithOrWithoutTrailingSlashExistingOrNot) {
  for (const char* name : {"frames/", "frames"}) {
    for (bool existing : {false, true}) {
      TempDir dir;
      if (existing) std::filesystem::create_directory(dir / "frames");
      ExportOptions o;
      o.output = (dir / name).string();
      RunContext ctx;
      ASSERT_NO_THROW(ExportFrames(Frames(3), 3, 64, 48, o, ctx)) << name << " existing=" << existing;
      EXPECT_TRUE(std::filesystem::exists(dir / "frames" / "frame_000002.png")) << name;
      EXPECT_EQ(dir.List(), std::vector<std::string>{"frames"}) << name << " existing=" << existing;
      // A second export replaces the first one through the same spelling.
      ASSERT_NO_THROW(ExportFrames(Frames(2), 2, 64, 48, o, ctx)) << name;
      EXPECT_FALSE(std::filesystem::exists(dir / "frames" / "frame_000002.png")) << name;
      EXPECT_EQ(dir.List(), std::vector<std::string>{"frames"});
    }
  }
}

TEST(Export, PngSequenceNeverDeletesAFolderWithTheUsersFiles) {
  TempDir dir;
  std::filesystem::create_directory(dir / "frames");
  { std::ofstream(dir / "frames" / "notes.txt") << "mine"; }
  ExportOptions o;
  o.output = (dir / "frames/").string();
  RunContext ctx;
  try {
    ExportFrames(Frames(2), 2, 64, 48, o, ctx);
    FAIL() << "an export over a folder with other files must be refused";
  } catch (const Io& e) {
    EXPECT_NE(std::string(e.what()).find("notes.txt"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(std::filesystem::exists(dir / "frames" / "notes.txt"));
  EXPECT_EQ(dir.List(), std::vector<std::string>{"frames"});
}

TEST(Export, CancelLeavesNothingBehind) {
  for (const char* target : {"clip.mp4", "frames"}) {
    TempDir dir;
    ExportOptions o;
    o.output = (dir / target).string();
    RunContext ctx;
    auto producer = [&](int64_t i, ExportFrame& f) {
      if (i == 7) ctx.RequestCancel();
      return Disc(i, f);
    };
    EXPECT_THROW(ExportFrames(producer, 100, 64, 48, o, ctx), Cancelled);
    EXPECT_TRUE(dir.List().empty()) << target << " left " << dir.List().size() << " entries";
  }
}

TEST(Export, FailureKeepsThePreviousFileAndLeavesNoTemporaries) {
  TempDir dir;
  ExportOptions o;
  o.output = (dir / "clip.mp4").string();
  RunContext ctx;
  ExportFrames(Frames(4), 4, 64, 48, o, ctx);
  const auto size_before = std::filesystem::file_size(dir / "clip.mp4");
  auto failing = [](int64_t i, ExportFrame& f) {
    if (i == 3) throw InvalidInput("driver frame 3 is unreadable");
    return Disc(i, f);
  };
  EXPECT_THROW(ExportFrames(failing, 10, 64, 48, o, ctx), InvalidInput);
  EXPECT_EQ(dir.List(), std::vector<std::string>{"clip.mp4"});
  EXPECT_EQ(std::filesystem::file_size(dir / "clip.mp4"), size_before);
}

TEST(Export, BadRequestsGiveClearErrors) {
  TempDir dir;
  RunContext ctx;
  ExportOptions o;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o.output = (dir / "c.mp4").string();
  o.fps = 0;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o.fps = 25;
  o.format = "gif";
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o.format = "";
  EXPECT_THROW(ExportFrames(Frames(2), 2, 63, 48, o, ctx), InvalidInput);  // Odd width for H.264.
  auto wrong_size = [](int64_t i, ExportFrame& f) { return i < 2 && Disc(i, f, 32, 32); };
  EXPECT_THROW(ExportFrames(wrong_size, 2, 64, 48, o, ctx), InvalidInput);
  EXPECT_THROW(ExportFrames(Frames(0), 0, 64, 48, o, ctx), Io);  // No frames at all.
  ExportOptions missing;
  missing.output = (dir / "no" / "such" / "c.mp4").string();
  EXPECT_THROW(ExportFrames(Frames(2), 2, 64, 48, missing, ctx), Io);
  EXPECT_TRUE(dir.List().empty());
}

}  // namespace
}  // namespace avatar
