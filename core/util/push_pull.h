#pragma once
// Push-pull gap filling (the one implementation: the fit's UV texture and the detail path's
// source-view depth both use it).

#include <opencv2/core.hpp>

namespace avatar {

// `values` (CV_32F, 1 to 4 channels) with every pixel where `known` (CV_8UC1 of the same size,
// non-zero = known) is 0 filled from the known pixels around it: averages pushed down a pyramid
// of halved levels, then pulled back up, each level keeping its own average where it has data
// and taking the coarser estimate elsewhere. Known pixels come back near (not exactly) their
// values; zero where nothing is known. Throws InvalidInput for other types or sizes.
cv::Mat PushPullFill(const cv::Mat& values, const cv::Mat& known);

}  // namespace avatar
