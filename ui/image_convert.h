#pragma once
// Conversions between OpenCV images (core) and Qt images (ui).

#include <QImage>
#include <opencv2/core.hpp>

namespace avatar::ui {

// BGR8 -> QImage RGB888 (deep copy).
QImage ToQImage(const cv::Mat& bgr);
// Any QImage -> BGR8 cv::Mat (deep copy).
cv::Mat ToMat(const QImage& image);

}  // namespace avatar::ui
