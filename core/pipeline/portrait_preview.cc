#include "core/pipeline/portrait_preview.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>

#include "core/io/image_io.h"
#include "core/util/error.h"

namespace avatar {

void PreviewOptions::Validate() const {
  AVATAR_CHECK_OPTION(width >= 16 && width <= 8192) << "--width must be within 16..8192, got " << width;
  AVATAR_CHECK_OPTION(height >= 16 && height <= 8192) << "--height must be within 16..8192, got " << height;
}

cv::Mat LetterboxImage(const cv::Mat& image, int width, int height, cv::Rect* placed) {
  AVATAR_CHECK(!image.empty() && image.type() == CV_8UC3) << "LetterboxImage expects a BGR8 image";
  const double scale = std::min(double(width) / image.cols, double(height) / image.rows);
  const int w = std::max(1, static_cast<int>(std::lround(image.cols * scale)));
  const int h = std::max(1, static_cast<int>(std::lround(image.rows * scale)));
  cv::Mat canvas(height, width, CV_8UC3, cv::Scalar::all(0));
  const cv::Rect roi((width - w) / 2, (height - h) / 2, w, h);
  cv::Mat resized;
  cv::resize(image, resized, roi.size(), 0, 0, scale < 1.0 ? cv::INTER_AREA : cv::INTER_LINEAR);
  resized.copyTo(canvas(roi));
  if (placed != nullptr) *placed = roi;
  return canvas;
}

cv::Mat RenderPortraitPreview(const std::filesystem::path& portrait, const PreviewOptions& options, RunContext& ctx) {
  options.Validate();
  ctx.Report("load portrait", 0.0, portrait.string());
  const cv::Mat image = LoadImageBgr(portrait);
  ctx.Report("lay out viewport", 0.5);
  cv::Mat view = LetterboxImage(image, options.width, options.height);
  ctx.Report("done", 1.0);
  return view;
}

}  // namespace avatar
