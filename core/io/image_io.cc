#include "core/io/image_io.h"

#include <opencv2/imgcodecs.hpp>

// libjpeg's API needs <cstdio> before it.
#include <cstdio>
#include <csetjmp>

#include <jerror.h>
#include <jpeglib.h>

#include <cctype>
#include <climits>
#include <cstdint>
#include <cstdlib>
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

uint32_t LittleEndian32(const std::string& b, size_t at) {
  return uint32_t(uint8_t(b[at])) | (uint32_t(uint8_t(b[at + 1])) << 8) | (uint32_t(uint8_t(b[at + 2])) << 16) |
         (uint32_t(uint8_t(b[at + 3])) << 24);
}

uint16_t LittleEndian16(const std::string& b, size_t at) {
  return static_cast<uint16_t>(uint8_t(b[at]) | (uint8_t(b[at + 1]) << 8));
}

uint32_t LittleEndian24(const std::string& b, size_t at) {
  return uint32_t(uint8_t(b[at])) | (uint32_t(uint8_t(b[at + 1])) << 8) | (uint32_t(uint8_t(b[at + 2])) << 16);
}

bool IsPng(const std::string& b) { return b.size() >= 8 && b.compare(0, 8, "\x89PNG\r\n\x1a\n", 8) == 0; }
bool IsJpeg(const std::string& b) { return b.size() >= 3 && uint8_t(b[0]) == 0xFF && uint8_t(b[1]) == 0xD8; }

// Reads the declared size from PNG, JPEG, BMP, TIFF, WebP and PNM/PAM headers so that absurd
// sizes are refused before the decoder tries to allocate them. Other formats return nullopt.
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
  if (b.size() >= 26 && b[0] == 'B' && b[1] == 'M') {
    // BITMAPINFOHEADER and later: signed 32-bit width and height (negative height = top-down);
    // the old 12-byte core header: 16-bit sizes.
    const uint32_t dib = LittleEndian32(b, 14);
    if (dib == 12) return HeaderSize{LittleEndian16(b, 18), LittleEndian16(b, 20)};
    const int32_t w = static_cast<int32_t>(LittleEndian32(b, 18));
    const int32_t h = static_cast<int32_t>(LittleEndian32(b, 22));
    return HeaderSize{w, h == INT32_MIN ? int64_t{1} << 31 : std::abs(int64_t{h})};
  }
  if (b.size() >= 8 && ((b[0] == 'I' && b[1] == 'I' && b[2] == 42 && b[3] == 0) ||
                        (b[0] == 'M' && b[1] == 'M' && b[2] == 0 && b[3] == 42))) {
    // TIFF: the first directory's ImageWidth (256) and ImageLength (257), SHORT or LONG.
    const bool le = b[0] == 'I';
    auto u16 = [&](size_t at) { return le ? LittleEndian16(b, at) : BigEndian16(b, at); };
    auto u32 = [&](size_t at) { return le ? LittleEndian32(b, at) : BigEndian32(b, at); };
    const size_t ifd = u32(4);
    if (ifd + 2 > b.size()) return HeaderSize{};
    const size_t entries = u16(ifd);
    HeaderSize size;
    for (size_t k = 0; k < entries && ifd + 2 + 12 * (k + 1) <= b.size(); ++k) {
      const size_t e = ifd + 2 + 12 * k;
      const uint16_t tag = u16(e), type = u16(e + 2);
      if (tag != 256 && tag != 257) continue;
      const int64_t value = type == 3 ? u16(e + 8) : type == 4 ? u32(e + 8) : 0;
      (tag == 256 ? size.width : size.height) = value;
    }
    return size;
  }
  if (b.size() >= 30 && b.compare(0, 4, "RIFF") == 0 && b.compare(8, 4, "WEBP") == 0) {
    if (b.compare(12, 4, "VP8X") == 0) return HeaderSize{LittleEndian24(b, 24) + 1, LittleEndian24(b, 27) + 1};
    if (b.compare(12, 4, "VP8L") == 0 && uint8_t(b[20]) == 0x2F) {
      const uint32_t bits = LittleEndian32(b, 21);
      return HeaderSize{(bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1};
    }
    if (b.compare(12, 4, "VP8 ") == 0) return HeaderSize{LittleEndian16(b, 26) & 0x3FFF, LittleEndian16(b, 28) & 0x3FFF};
    return HeaderSize{};
  }
  if (b.size() >= 3 && b[0] == 'P' && b[1] >= '1' && b[1] <= '7') {
    // PBM/PGM/PPM (P1-P6): width and height are the first two numbers after the magic,
    // with # comments allowed between the fields. PAM (P7) names them WIDTH and HEIGHT.
    size_t i = 2;
    auto skip = [&] {
      while (i < b.size() && (std::isspace(static_cast<unsigned char>(b[i])) || b[i] == '#')) {
        if (b[i] == '#') {
          while (i < b.size() && b[i] != '\n') ++i;
        } else {
          ++i;
        }
      }
    };
    auto number = [&]() -> int64_t {
      skip();
      int64_t v = 0;
      bool any = false;
      while (i < b.size() && std::isdigit(static_cast<unsigned char>(b[i])) && v < (int64_t{1} << 40)) {
        v = v * 10 + (b[i++] - '0');
        any = true;
      }
      return any ? v : 0;
    };
    if (b[1] == '7') {
      HeaderSize size;
      const size_t w = b.find("WIDTH"), h = b.find("HEIGHT");
      if (w != std::string::npos) {
        i = w + 5;
        size.width = number();
      }
      if (h != std::string::npos) {
        i = h + 6;
        size.height = number();
      }
      return size;
    }
    const int64_t w = number();
    const int64_t h = number();
    return HeaderSize{w, h};
  }
  return std::nullopt;
}

// libjpeg reports damaged entropy-coded data as warnings and decodes on, filling the damage with
// grey or smeared blocks; OpenCV prints them to stderr and returns the image. The first damage
// warning is kept here so that the file is refused instead. Benign warnings (extraneous bytes
// before a marker, written by some cameras) are not damage.
struct JpegCheck {
  jpeg_error_mgr manager;  // First member: libjpeg passes a pointer to it.
  std::jmp_buf fatal;
  char message[JMSG_LENGTH_MAX] = {};
  bool damaged = false;
};

[[noreturn]] void JpegFatal(j_common_ptr info) {
  auto* check = reinterpret_cast<JpegCheck*>(info->err);
  (*info->err->format_message)(info, check->message);
  std::longjmp(check->fatal, 1);
}

void JpegMessage(j_common_ptr info, int level) {
  auto* check = reinterpret_cast<JpegCheck*>(info->err);
  if (level >= 0 || check->damaged) return;  // Trace messages, or damage already found.
  if (info->err->msg_code == JWRN_EXTRANEOUS_DATA) return;
  check->damaged = true;
  (*info->err->format_message)(info, check->message);
}

// "" when libjpeg decodes `bytes` without damage (at 1/8 scale: every coefficient is still
// decoded, only the inverse DCT is cheaper), else libjpeg's message.
std::string JpegDamage(const std::string& bytes) {
  jpeg_decompress_struct info{};
  JpegCheck check;
  info.err = jpeg_std_error(&check.manager);
  check.manager.error_exit = JpegFatal;
  check.manager.emit_message = JpegMessage;
  // Nothing with a destructor lives between setjmp and the longjmps below.
  if (setjmp(check.fatal) != 0) {
    jpeg_destroy_decompress(&info);
    return check.message[0] != 0 ? std::string(check.message) : std::string("undecodable JPEG data");
  }
  jpeg_create_decompress(&info);
  jpeg_mem_src(&info, reinterpret_cast<const unsigned char*>(bytes.data()), static_cast<unsigned long>(bytes.size()));
  jpeg_read_header(&info, TRUE);
  info.scale_num = 1;
  info.scale_denom = 8;
  jpeg_start_decompress(&info);
  const JDIMENSION row_bytes = info.output_width * static_cast<JDIMENSION>(info.output_components);
  JSAMPARRAY row = (*info.mem->alloc_sarray)(reinterpret_cast<j_common_ptr>(&info), JPOOL_IMAGE, row_bytes, 1);
  while (info.output_scanline < info.output_height && !check.damaged) jpeg_read_scanlines(&info, row, 1);
  if (!check.damaged) jpeg_finish_decompress(&info);
  jpeg_destroy_decompress(&info);
  return check.damaged ? std::string(check.message) : std::string();
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
      const std::string damage = JpegDamage(bytes);
      if (!damage.empty()) {
        throw InvalidInput("image file " + name + " is damaged (" + damage +
                           "); copy it again or re-export it from an image editor");
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
