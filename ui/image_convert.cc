#include "ui/image_convert.h"

#include <opencv2/imgproc.hpp>

#include "core/util/error.h"

namespace avatar::ui {

QImage ToQImage(const cv::Mat& bgr) {
  AVATAR_CHECK(bgr.type() == CV_8UC3) << "ToQImage expects BGR8";
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  return QImage(rgb.data, rgb.cols, rgb.rows, static_cast<qsizetype>(rgb.step), QImage::Format_RGB888).copy();
}

cv::Mat ToMat(const QImage& image) {
  const QImage rgb = image.convertToFormat(QImage::Format_RGB888);
  const cv::Mat view(rgb.height(), rgb.width(), CV_8UC3, const_cast<uchar*>(rgb.constBits()),
                     static_cast<size_t>(rgb.bytesPerLine()));
  cv::Mat bgr;
  cv::cvtColor(view, bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

}  // namespace avatar::ui
