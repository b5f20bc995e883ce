// The bad-input corpus: each file is made here (from the installed samples or from scratch)
// and given to the real `avatar-studio analyze --json`. Every case must end cleanly, within a
// time limit, with either a documented success or a typed error whose message names the
// problem; never a crash or a hang.
#include <jpeglib.h>

#include <cstdio>
#include <fstream>
#include <functional>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/run_process.h"
#include "common/temp_dir.h"
#include "face/face_test_util.h"

namespace avatar::face {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

uint32_t Crc32(const std::string& data) {
  uint32_t c = 0xFFFFFFFFu;
  for (unsigned char b : data) {
    c ^= b;
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
  }
  return ~c;
}

std::string Be32(uint32_t v) {
  return {static_cast<char>(v >> 24), static_cast<char>(v >> 16), static_cast<char>(v >> 8), static_cast<char>(v)};
}

// A valid-looking PNG header declaring width x height, with no pixel data worth decoding.
std::string PngHeaderOnly(uint32_t width, uint32_t height) {
  std::string ihdr = "IHDR" + Be32(width) + Be32(height) + std::string("\x08\x02\x00\x00\x00", 5);
  std::string png = "\x89PNG\r\n\x1a\n";
  png += Be32(13) + ihdr + Be32(Crc32(ihdr));
  png += Be32(0) + std::string("IEND") + Be32(Crc32("IEND"));
  return png;
}

void WriteBytes(const fs::path& path, const std::string& bytes) { std::ofstream(path, std::ios::binary) << bytes; }

std::string ReadBytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// A CMYK (Adobe-style inverted) JPEG of `bgr`, written with libjpeg.
void WriteCmykJpeg(const fs::path& path, const cv::Mat& bgr) {
  jpeg_compress_struct cinfo;
  jpeg_error_mgr jerr;
  cinfo.err = jpeg_std_error(&jerr);
  jpeg_create_compress(&cinfo);
  FILE* f = std::fopen(path.c_str(), "wb");
  ASSERT_NE(f, nullptr);
  jpeg_stdio_dest(&cinfo, f);
  cinfo.image_width = bgr.cols;
  cinfo.image_height = bgr.rows;
  cinfo.input_components = 4;
  cinfo.in_color_space = JCS_CMYK;
  jpeg_set_defaults(&cinfo);
  jpeg_set_colorspace(&cinfo, JCS_CMYK);
  jpeg_set_quality(&cinfo, 92, TRUE);
  jpeg_start_compress(&cinfo, TRUE);
  std::vector<unsigned char> row(bgr.cols * 4);
  while (cinfo.next_scanline < cinfo.image_height) {
    const cv::Vec3b* px = bgr.ptr<cv::Vec3b>(cinfo.next_scanline);
    for (int x = 0; x < bgr.cols; ++x) {
      const int r = px[x][2], g = px[x][1], b = px[x][0];
      const int k = 255 - std::max({r, g, b});
      const int d = 255 - k;
      const auto ink = [&](int v) { return d == 0 ? 0 : (255 * (d - v)) / d; };
      // Inverted values, as Adobe writes them (and as decoders expect).
      row[4 * x + 0] = static_cast<unsigned char>(255 - ink(r));
      row[4 * x + 1] = static_cast<unsigned char>(255 - ink(g));
      row[4 * x + 2] = static_cast<unsigned char>(255 - ink(b));
      row[4 * x + 3] = static_cast<unsigned char>(255 - k);
    }
    unsigned char* rows[1] = {row.data()};
    jpeg_write_scanlines(&cinfo, rows, 1);
  }
  jpeg_finish_compress(&cinfo);
  jpeg_destroy_compress(&cinfo);
  std::fclose(f);
}

// A JPEG whose pixels are `bgr` turned 90 degrees counter-clockwise, with an EXIF tag
// (orientation 6) telling viewers to turn it back clockwise.
std::string JpegWithExifRotation(const cv::Mat& bgr) {
  cv::Mat turned;
  cv::rotate(bgr, turned, cv::ROTATE_90_COUNTERCLOCKWISE);
  std::vector<uchar> buf;
  cv::imencode(".jpg", turned, buf);
  const std::string jpeg(buf.begin(), buf.end());
  // TIFF (little endian): header, IFD with one entry 0x0112 SHORT 1 = 6, no next IFD.
  std::string tiff("II*\0\x08\0\0\0", 8);
  tiff += std::string("\x01\0", 2);                                  // one entry
  tiff += std::string("\x12\x01\x03\0\x01\0\0\0\x06\0\0\0", 12);     // orientation = 6
  tiff += std::string("\0\0\0\0", 4);                                // no next IFD
  const std::string payload = std::string("Exif\0\0", 6) + tiff;
  const uint16_t len = static_cast<uint16_t>(payload.size() + 2);
  const std::string app1 = std::string("\xFF\xE1", 2) + static_cast<char>(len >> 8) + static_cast<char>(len & 0xFF) + payload;
  return jpeg.substr(0, 2) + app1 + jpeg.substr(2);
}

enum class Expect { kOk, kError };

struct BadCase {
  std::string name;
  std::string file;                                  // file name inside the temp folder
  std::function<void(const fs::path&)> make;         // writes the file
  Expect expect;
  std::vector<std::string> message;                  // substrings of stderr (error) or checks
  int faces = -1;                                    // kOk: expected face count (-1 = any >= 1)
  std::string extra_args;
};

cv::Mat Grace() { return testing::LoadSample("grace_hopper.jpg"); }

// Grace Hopper shrunk onto a grey canvas so that her face box is about `face_px` (measured:
// 36 gives a 44 px box, accepted with the soft-result warning; 16 gives 14 px, refused).
cv::Mat GraceOnCanvas(double face_px) {
  const auto faces = testing::Analyzer().Detect(Grace());
  const double scale = face_px / std::max(faces.at(0).box.width, faces.at(0).box.height);
  cv::Mat small, canvas(400, 400, CV_8UC3, cv::Scalar::all(120));
  cv::resize(Grace(), small, cv::Size(), scale, scale, cv::INTER_AREA);
  small.copyTo(canvas(cv::Rect(150, 150, small.cols, small.rows)));
  return canvas;
}

const std::vector<BadCase>& Cases() {
  static const std::vector<BadCase> cases = {
      {"NoFace", "landscape.png",
       [](const fs::path& p) {
         cv::Mat m(400, 600, CV_8UC3);
         for (int y = 0; y < m.rows; ++y) m.row(y).setTo(cv::Scalar(200 - y / 3, 150, 80 + y / 4));
         cv::imwrite(p.string(), m);
       },
       Expect::kError, {"no face found", "landscape.png"}},
      {"SeveralFacesPicksTheMainOne", "group.jpg",
       [](const fs::path& p) { fs::copy_file(testing::Sample("sample1.jpg"), p); }, Expect::kOk, {}, 3},
      {"TinyFace", "tiny.png",
       [](const fs::path& p) { cv::imwrite(p.string(), GraceOnCanvas(16)); },
       Expect::kError, {"tiny.png", "too small"}},
      {"SmallFaceIsSoft", "small.png",
       [](const fs::path& p) { cv::imwrite(p.string(), GraceOnCanvas(36)); },
       Expect::kOk, {"warning", "small.png", "soft"}, 1},
      {"FaceCutByTheBorder", "cut.png",
       [](const fs::path& p) { cv::imwrite(p.string(), Grace()(cv::Rect(250, 60, 262, 540))); }, Expect::kOk, {}, -1},
      {"ProfileView", "profile.jpg",
       // sample2's face 1 (second by rank) is the woman in profile on the left.
       [](const fs::path& p) { fs::copy_file(testing::Sample("sample2.jpg"), p); }, Expect::kError,
       {"profile.jpg", "turned too far"}, -1, "--face-index 1"},
      {"Grayscale", "grey.jpg",
       [](const fs::path& p) {
         cv::Mat g;
         cv::cvtColor(Grace(), g, cv::COLOR_BGR2GRAY);
         cv::imwrite(p.string(), g);
       },
       Expect::kOk, {}, 1},
      {"CmykJpeg", "cmyk.jpg", [](const fs::path& p) { WriteCmykJpeg(p, Grace()); }, Expect::kOk, {}, 1},
      {"PngWithAlpha", "alpha.png",
       [](const fs::path& p) {
         cv::Mat bgra;
         cv::cvtColor(Grace(), bgra, cv::COLOR_BGR2BGRA);
         for (int y = 0; y < bgra.rows; ++y) {
           for (int x = 0; x < bgra.cols; ++x) bgra.at<cv::Vec4b>(y, x)[3] = static_cast<uchar>(x % 256);
         }
         cv::imwrite(p.string(), bgra);
       },
       Expect::kOk, {}, 1},
      {"Png16Bit", "deep.png",
       [](const fs::path& p) {
         cv::Mat deep;
         Grace().convertTo(deep, CV_16UC3, 257.0);
         cv::imwrite(p.string(), deep);
       },
       Expect::kOk, {}, 1},
      {"ExifRotation", "exif.jpg", [](const fs::path& p) { WriteBytes(p, JpegWithExifRotation(Grace())); },
       Expect::kOk, {"upright"}, 1},
      {"HugeHeader20000", "huge.png", [](const fs::path& p) { WriteBytes(p, PngHeaderOnly(20000, 20000)); },
       Expect::kError, {"20000x20000", "huge.png"}},
      {"ZeroByteImage", "empty.jpg", [](const fs::path& p) { WriteBytes(p, ""); }, Expect::kError, {"empty", "empty.jpg"}},
      {"TruncatedJpeg", "truncated.jpg",
       [](const fs::path& p) {
         const std::string b = ReadBytes(testing::Sample("grace_hopper.jpg"));
         WriteBytes(p, b.substr(0, b.size() / 3));
       },
       Expect::kError, {"truncated", "truncated.jpg"}},
      {"TruncatedPng", "truncated.png",
       [](const fs::path& p) {
         std::vector<uchar> buf;
         cv::imencode(".png", Grace(), buf);
         WriteBytes(p, std::string(buf.begin(), buf.begin() + buf.size() / 2));
       },
       // Its header is whole (so no size or header complaint): the decoder gives up on the pixels.
       Expect::kError, {"truncated.png", "cannot decode image"}},
      {"TextPretendingToBeJpeg", "notes.jpg", [](const fs::path& p) { WriteBytes(p, "just some text, not a photo\n"); },
       Expect::kError, {"notes.jpg", "not a supported image"}},
      {"RandomBytesPng", "noise.png",
       [](const fs::path& p) {
         std::string s = "\x89PNG\r\n\x1a\n";
         for (int i = 0; i < 5000; ++i) s.push_back(static_cast<char>((i * 7919) % 251));
         WriteBytes(p, s);
       },
       // The bytes where IHDR keeps the size declare 1693351180 x 2519052094 pixels: refused before decoding.
       Expect::kError, {"noise.png", "declares 1693351180x2519052094 pixels, above the limit"}},
      {"MissingFile", "does_not_exist.jpg", [](const fs::path&) {}, Expect::kError, {"not found", "does_not_exist.jpg"}},
      {"Folder", "folder.jpg", [](const fs::path& p) { fs::create_directories(p); }, Expect::kError, {"folder"}},
      {"OnePixel", "pixel.png", [](const fs::path& p) { cv::imwrite(p.string(), cv::Mat(1, 1, CV_8UC3, cv::Scalar(1, 2, 3))); },
       Expect::kError, {"no face found"}},
      {"ExtremeAspect", "strip.png",
       [](const fs::path& p) { cv::imwrite(p.string(), cv::Mat(4, 8000, CV_8UC3, cv::Scalar(90, 90, 90))); },
       Expect::kError, {"no face found"}},
      {"AllBlack", "black.jpg", [](const fs::path& p) { cv::imwrite(p.string(), cv::Mat(480, 640, CV_8UC3, cv::Scalar::all(0))); },
       Expect::kError, {"no face found"}},
      {"ZeroByteVideo", "empty.mp4", [](const fs::path& p) { WriteBytes(p, ""); }, Expect::kError, {"empty", "empty.mp4"}},
      {"VideoWithNoFrames", "audio_only.mp4",
       [](const fs::path& p) {
         const std::string cmd = "ffmpeg -loglevel error -y -f lavfi -i anullsrc=r=8000:cl=mono -t 0.5 -c:a aac '" +
                                 p.string() + "'";
         ASSERT_EQ(std::system(cmd.c_str()), 0) << "ffmpeg is needed to make this case (scripts/setup installs it)";
       },
       // No video stream: the video reader does not open it.
       Expect::kError, {"audio_only.mp4", "as a video: the file is damaged or not a supported format"}},
      {"TruncatedVideo", "cut.mp4",
       // Cut before the index (the "moov atom") the container needs.
       [](const fs::path& p) { WriteBytes(p, ReadBytes(testing::Sample("franck.mp4")).substr(0, 2000)); },
       Expect::kError, {"cut.mp4", "as a video: the file is damaged or not a supported format"}},
      {"BadFaceIndex", "index.jpg", [](const fs::path& p) { fs::copy_file(testing::Sample("grace_hopper.jpg"), p); },
       Expect::kError, {"only 1 face"}, -1, "--face-index 3"},
  };
  return cases;
}

class BadInput : public ::testing::TestWithParam<int> {};

TEST_P(BadInput, CleanOutcome) {
  const BadCase& c = Cases()[GetParam()];
  avatar::testing::TempDir dir;
  const fs::path file = dir / c.file;
  c.make(file);
  ASSERT_FALSE(::testing::Test::HasFatalFailure());
  // `timeout` turns a hang into exit code 124; a crash shows as a signal (exit > 128).
  const auto r = avatar::testing::RunProcess("timeout 120 '" + std::string(AVATAR_STUDIO_EXE) + "' analyze '" +
                                             file.string() + "' --json --threads 2 " + c.extra_args);
  ASSERT_NE(r.exit_code, 124) << c.name << ": analyze hung";
  ASSERT_TRUE(r.exit_code == 0 || r.exit_code == 1) << c.name << ": exit code " << r.exit_code << "\n" << r.err;
  if (c.expect == Expect::kOk) {
    ASSERT_EQ(r.exit_code, 0) << c.name << ": " << r.err;
    const json report = json::parse(r.out);
    if (c.faces >= 0) EXPECT_EQ(report["faces"].size(), static_cast<size_t>(c.faces)) << c.name;
    EXPECT_GE(report["faces"].size(), 1u);
    EXPECT_NEAR(report["embedding_norm"].get<double>(), 1.0, 1e-3);
    for (const auto& m : c.message) {
      if (m == "upright") {
        // EXIF orientation applied: the face is upright again (small roll) in a portrait frame.
        EXPECT_GT(report["height"].get<int>(), report["width"].get<int>());
        EXPECT_LT(std::abs(report["pose"]["roll"].get<double>()), 15.0);
      } else {
        // Anything else is a warning the user must see on stderr (and in the report).
        EXPECT_NE(r.err.find(m), std::string::npos) << c.name << ": '" << m << "' not in: " << r.err;
        EXPECT_FALSE(report["warnings"].empty()) << c.name;
      }
    }
    if (c.message.empty()) EXPECT_TRUE(report["warnings"].empty()) << c.name << ": " << report["warnings"].dump();
  } else {
    ASSERT_EQ(r.exit_code, 1) << c.name << ": expected a clean error, got success:\n" << r.out.substr(0, 300);
    EXPECT_TRUE(r.out.empty()) << c.name << ": no report on stdout after an error";
    for (const auto& m : c.message) EXPECT_NE(r.err.find(m), std::string::npos) << c.name << ": '" << m << "' not in: " << r.err;
    EXPECT_EQ(r.err.find("terminate called"), std::string::npos) << r.err;
  }
  std::cout << "[bad-input] " << c.name << ": exit " << r.exit_code << " " << r.err.substr(0, 200) << "\n";
}

INSTANTIATE_TEST_SUITE_P(Corpus, BadInput, ::testing::Range(0, static_cast<int>(Cases().size())),
                         [](const auto& info) { return Cases()[info.param].name; });

TEST(BadInputCorpus, HasAtLeastTwentyCases) { EXPECT_GE(Cases().size(), 20u); }

}  // namespace
}  // namespace avatar::face
