#include "core/io/image_io.h"

#include <opencv2/imgcodecs.hpp>

#include <cstdint>
#include <optional>
#include <string>

#include "core/io/atomic_file.h"
#include "core/util/error.h"

namespace avatar {
namespace fs = std::filesystem;

namespace {

struct HeaderSize {
  int64_t width = 0;
  int64_t height = 0;
};

uint32_t BigEndian32(const std::string& b, size_t at) {
  return (uint32_t(uint8_t(b[at])) << 24) | (uint32_t(uint8_t(b[at + 1])) << 16) |
         (uint32_t(uint8_t(b[at + 2])) << 8) | uint32_t(uint8_t(b[at + 3]));
}

uint16_t BigEndian16(const std::string& b, size_t at) {
  return static_cast<uint16_t>((uint8_t(b[at]) << 8) | uint8_t(b[at + 1]));
}

bool IsPng(const std::string& b) { return b.size() >= 8 && b.compare(0, 8, "\x89PNG\r\n\x1a\n", 8) == 0; }
bool IsJpeg(const std::string& b) { return b.size() >= 3 && uint8_t(b[0]) == 0xFF && uint8_t(b[1]) == 0xD8; }

// Reads the declared size from PNG and JPEG headers so that absurd sizes are refused
// before the decoder tries to allocate them. Other formats return nullopt.
std::optional<HeaderSize> ReadHeaderSize(const std::string& b) {
  if (IsPng(b)) {
    if (b.size() < 24) return HeaderSize{};
    return HeaderSize{BigEndian32(b, 16), BigEndian32(b, 20)};
  }
  if (IsJpeg(b)) {
    size_t i = 2;
    while (i + 9 < b.size()) {
      if (uint8_t(b[i]) != 0xFF) return HeaderSize{};
      const uint8_t marker = uint8_t(b[i + 1]);
      if (marker == 0xFF) {  // Fill byte.
        ++i;
        continue;
      }
      const bool is_sof = marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC;
      if (is_sof) return HeaderSize{BigEndian16(b, i + 7), BigEndian16(b, i + 5)};
      i += 2 + BigEndian16(b, i + 2);
    }
    return HeaderSize{};
  }
  return std::nullopt;
}

}  // namespace

cv::Mat LoadImageBgr(const fs::path& path, const ImageLoadOptions& options) {
  const std::string name = "'" + path.string() + "'";
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Io("image file not found: " + name + "; check the path");
  if (fs::is_directory(path, ec)) throw Io(name + " is a folder; choose an image file (JPEG or PNG)");
  const auto size = fs::file_size(path, ec);
  if (ec) throw Io("cannot read " + name + ": " + ec.message());
  if (size == 0) throw InvalidInput("image file " + name + " is empty (0 bytes); choose another photo");
  if (static_cast<int64_t>(size) > options.max_bytes) {
    throw InvalidInput("image file " + name + " is " + std::to_string(size >> 20) +
                       " MB, more than the limit; resize it below " + std::to_string(options.max_side) + " px");
  }
  const std::string bytes = ReadFileBytes(path);
  if (auto header = ReadHeaderSize(bytes)) {
    if (header->width <= 0 || header->height <= 0) {
      throw InvalidInput("image file " + name + " has a damaged header; re-export it from an image editor");
    }
    if (header->width > options.max_side || header->height > options.max_side) {
      throw InvalidInput("image " + name + " declares " + std::to_string(header->width) + "x" +
                         std::to_string(header->height) + " pixels, above the limit of " +
                         std::to_string(options.max_side) + " px per side; resize it first");
    }
    if (IsJpeg(bytes)) {
      // A JPEG must end with the EOI marker (possibly followed by padding); without it the
      // decoder silently fills the missing part with grey.
      const size_t eoi = bytes.rfind("\xFF\xD9");
      if (eoi == std::string::npos || bytes.size() - eoi > 4096) {
        throw InvalidInput("image file " + name + " is truncated (the JPEG has no end marker); copy it again");
      }
    }
  }
  cv::Mat decoded;
  try {
    const cv::Mat raw(1, static_cast<int>(bytes.size()), CV_8UC1, const_cast<char*>(bytes.data()));
    decoded = cv::imdecode(raw, cv::IMREAD_COLOR);  // BGR8, EXIF orientation applied.
  } catch (const cv::Exception& e) {
    throw InvalidInput("cannot decode image " + name + ": " + e.err);
  }
  if (decoded.empty()) {
    throw InvalidInput("cannot decode image " + name + ": not a supported image (use JPEG, PNG, BMP, TIFF or WebP)");
  }
  return decoded;
}

void SaveImage(const fs::path& path, const cv::Mat& image) {
  AVATAR_CHECK_INPUT(!image.empty()) << "refusing to write an empty image to '" << path.string() << "'";
  WriteFileAtomically(path, [&](const fs::path& temp) {
    bool ok = false;
    try {
      ok = cv::imwrite(temp.string(), image);
    } catch (const cv::Exception& e) {
      throw Io("cannot write image '" + path.string() + "': " + e.err);
    }
    if (!ok) throw Io("cannot write image '" + path.string() + "'; check the extension (.png, .jpg) and free space");
  });
}

}  // namespace avatar
