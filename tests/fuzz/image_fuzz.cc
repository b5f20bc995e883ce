// Fuzz target "image": photo decoding (core/io/image_io LoadImageBgr: size checks, the libjpeg
// damage check, OpenCV's decoders, EXIF orientation, bit depth and channel conversion).
// The largest side is capped at 2048 (the default 16384 would let one input allocate ~800 MB,
// beyond the fuzzer's memory limit; the size check itself is the same code).
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/io/image_io.h"
#include "core/util/error.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

std::string RunImage(std::string_view input) {
  const std::filesystem::path file = FreshInputDir() / "photo.img";
  WriteFile(file, input);
  return AcceptAvatarErrors([&] {
    ImageLoadOptions options;
    options.max_side = 2048;
    const cv::Mat bgr = LoadImageBgr(file, options);
    if (bgr.empty() || bgr.type() != CV_8UC3) throw std::logic_error("LoadImageBgr returned a non-BGR8 image");
  });
}

int ImageSeeds(const std::filesystem::path& dir) {
  int n = 0;
  // Small images of every format and depth the app reads, made here.
  cv::Mat bgr(12, 16, CV_8UC3);
  cv::randu(bgr, 0, 255);
  cv::Mat grey, bgra, bgr16;
  cv::cvtColor(bgr, grey, cv::COLOR_BGR2GRAY);
  cv::cvtColor(bgr, bgra, cv::COLOR_BGR2BGRA);
  bgr.convertTo(bgr16, CV_16UC3, 257.0);
  auto write = [&](const std::string& name, const cv::Mat& m, const std::vector<int>& params = {}) {
    std::vector<uchar> bytes;
    if (!cv::imencode(std::filesystem::path(name).extension().string(), m, bytes, params)) return;
    WriteFile(dir / name, std::string(bytes.begin(), bytes.end()));
    ++n;
  };
  write("bgr.png", bgr);
  write("grey.png", grey);
  write("alpha.png", bgra);
  write("deep.png", bgr16);
  write("bgr.jpg", bgr, {cv::IMWRITE_JPEG_QUALITY, 80});
  write("progressive.jpg", bgr, {cv::IMWRITE_JPEG_PROGRESSIVE, 1});
  write("grey.jpg", grey);
  write("bgr.bmp", bgr);
  write("bgr.tif", bgr);
  write("deep.tif", bgr16);
  write("bgr.webp", bgr, {cv::IMWRITE_WEBP_QUALITY, 90});
  // One real camera photo of the data folder, when it is small.
  const std::filesystem::path photo = DataDir() / "samples" / "sample1.jpg";
  std::error_code ec;
  if (!DataDir().empty() && std::filesystem::is_regular_file(photo, ec) &&
      std::filesystem::file_size(photo) < (1u << 20)) {
    std::filesystem::copy_file(photo, dir / "sample1.jpg", std::filesystem::copy_options::overwrite_existing);
    ++n;
  }
  return n;
}

AVATAR_FUZZ_TARGET("image", RunImage, ImageSeeds);

}  // namespace
}  // namespace avatar::fuzz
