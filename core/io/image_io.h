#pragma once
// Image files in and out, with clear errors for every kind of bad file.

#include <filesystem>

#include <opencv2/core.hpp>

namespace avatar {

struct ImageLoadOptions {
  // Largest accepted width or height in pixels; bigger images are refused before decoding.
  int max_side = 16384;
  // Largest accepted file size in bytes.
  int64_t max_bytes = int64_t{512} << 20;
};

// Loads an image as 8-bit BGR (alpha dropped, grey expanded, 16-bit scaled, EXIF
// orientation applied). Throws Io (missing/unreadable file) or InvalidInput (empty,
// truncated, not an image, too large), each naming the file and what to do.
cv::Mat LoadImageBgr(const std::filesystem::path& path, const ImageLoadOptions& options = {});

// Writes an image atomically (temporary file + rename). The format follows the extension.
// Throws Io naming the file on failure.
void SaveImage(const std::filesystem::path& path, const cv::Mat& image);

}  // namespace avatar
