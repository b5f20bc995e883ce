#include "core/io/image_io.h"

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include <fstream>

#include "common/temp_dir.h"
#include "core/io/atomic_file.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;

cv::Mat Pattern(int w, int h, int type = CV_8UC3) {
  cv::Mat m(h, w, type);
  cv::randu(m, cv::Scalar::all(0), cv::Scalar::all(type == CV_16UC3 ? 65535 : 255));
  return m;
}

std::string Bytes(const cv::Mat& m, const std::string& ext) {
  std::vector<uchar> buf;
  cv::imencode(ext, m, buf);
  return std::string(buf.begin(), buf.end());
}

template <typename E>
std::string ErrorOf(const std::filesystem::path& p) {
  try {
    LoadImageBgr(p);
  } catch (const E& e) {
    return e.what();
  } catch (const std::exception& e) {
    return std::string("<wrong type> ") + e.what();
  }
  return "<no error>";
}

TEST(ImageIo, LoadsPngExactly) {
  TempDir dir;
  const cv::Mat m = Pattern(37, 23);
  SaveImage(dir / "a.png", m);
  const cv::Mat back = LoadImageBgr(dir / "a.png");
  ASSERT_EQ(back.type(), CV_8UC3);
  EXPECT_EQ(cv::norm(back, m, cv::NORM_INF), 0.0);
}

TEST(ImageIo, NormalisesGreyAlphaAndSixteenBit) {
  TempDir dir;
  cv::Mat grey = Pattern(8, 8, CV_8UC1);
  cv::imwrite((dir / "g.png").string(), grey);
  cv::Mat rgba(8, 8, CV_8UC4, cv::Scalar(10, 20, 30, 0));
  cv::imwrite((dir / "a.png").string(), rgba);
  cv::Mat deep(8, 8, CV_16UC3, cv::Scalar(65535, 0, 32768));
  cv::imwrite((dir / "d.png").string(), deep);
  for (const char* name : {"g.png", "a.png", "d.png"}) {
    const cv::Mat m = LoadImageBgr(dir / name);
    EXPECT_EQ(m.type(), CV_8UC3) << name;
    EXPECT_EQ(m.size(), cv::Size(8, 8)) << name;
  }
  EXPECT_EQ(LoadImageBgr(dir / "d.png").at<cv::Vec3b>(0, 0), cv::Vec3b(255, 0, 128));
}

TEST(ImageIo, BadFilesGiveClearErrorsNamingTheFile) {
  TempDir dir;
  EXPECT_NE(ErrorOf<Io>(dir / "missing.jpg").find("missing.jpg"), std::string::npos);
  EXPECT_NE(ErrorOf<Io>(dir.path()).find("folder"), std::string::npos);

  WriteBytesAtomically(dir / "zero.jpg", "");
  EXPECT_NE(ErrorOf<InvalidInput>(dir / "zero.jpg").find("0 bytes"), std::string::npos);

  WriteBytesAtomically(dir / "text.png", "this is not an image at all");
  EXPECT_NE(ErrorOf<InvalidInput>(dir / "text.png").find("text.png"), std::string::npos);

  const std::string jpeg = Bytes(Pattern(64, 64), ".jpg");
  WriteBytesAtomically(dir / "cut.jpg", jpeg.substr(0, jpeg.size() / 2));
  EXPECT_NE(ErrorOf<InvalidInput>(dir / "cut.jpg").find("truncated"), std::string::npos);

  // A PNG whose header declares 20000 x 20000 pixels is refused before decoding.
  std::string png = Bytes(Pattern(4, 4), ".png");
  const unsigned char big[8] = {0, 0, 0x4E, 0x20, 0, 0, 0x4E, 0x20};
  png.replace(16, 8, reinterpret_cast<const char*>(big), 8);
  WriteBytesAtomically(dir / "huge.png", png);
  EXPECT_NE(ErrorOf<InvalidInput>(dir / "huge.png").find("20000x20000"), std::string::npos);

  const std::string png_ok = Bytes(Pattern(16, 16), ".png");
  WriteBytesAtomically(dir / "cut.png", png_ok.substr(0, 40));
  EXPECT_NE(ErrorOf<InvalidInput>(dir / "cut.png").find("cut.png"), std::string::npos);
}

TEST(ImageIo, SaveRefusesEmptyAndMissingFolders) {
  TempDir dir;
  EXPECT_THROW(SaveImage(dir / "e.png", cv::Mat()), InvalidInput);
  EXPECT_THROW(SaveImage(dir / "no" / "such" / "x.png", Pattern(4, 4)), Io);
  EXPECT_THROW(SaveImage(dir / "x.unknownext", Pattern(4, 4)), Io);
  EXPECT_TRUE(dir.List().empty()) << "failed saves must leave nothing behind";
}

}  // namespace
}  // namespace avatar
