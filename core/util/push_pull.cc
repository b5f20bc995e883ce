#include "core/util/push_pull.h"

#include <vector>

#include <opencv2/imgproc.hpp>

#include "core/util/error.h"

namespace avatar {
namespace {

// A one-channel map repeated over `channels` channels.
cv::Mat RepeatChannels(const cv::Mat& one, int channels) {
  if (channels == 1) return one;
  cv::Mat out;
  cv::merge(std::vector<cv::Mat>(static_cast<size_t>(channels), one), out);
  return out;
}

}  // namespace

cv::Mat PushPullFill(const cv::Mat& values, const cv::Mat& known) {
  AVATAR_CHECK_INPUT(!values.empty() && values.depth() == CV_32F && values.channels() <= 4)
      << "push-pull: the values must be CV_32F with 1 to 4 channels";
  AVATAR_CHECK_INPUT(known.type() == CV_8UC1 && known.size() == values.size())
      << "push-pull: the known mask must be CV_8UC1 of the values' size";
  const int channels = values.channels();
  cv::Mat w;
  const cv::Mat known01 = known != 0;
  known01.convertTo(w, CV_32FC1, 1.0 / 255.0);
  // Push: weight-premultiplied values and the weights averaged down to one pixel.
  std::vector<cv::Mat> v_levels{values.mul(RepeatChannels(w, channels))};
  std::vector<cv::Mat> w_levels{w};
  while (v_levels.back().cols > 1 || v_levels.back().rows > 1) {
    const cv::Size half((v_levels.back().cols + 1) / 2, (v_levels.back().rows + 1) / 2);
    cv::Mat v, ww;
    cv::resize(v_levels.back(), v, half, 0, 0, cv::INTER_AREA);
    cv::resize(w_levels.back(), ww, half, 0, 0, cv::INTER_AREA);
    v_levels.push_back(v);
    w_levels.push_back(ww);
  }
  // Pull: from the coarsest level up, each level's own average blended with the coarser estimate
  // by how much of it is known.
  cv::Mat estimate;
  for (int l = static_cast<int>(v_levels.size()) - 1; l >= 0; --l) {
    cv::Mat safe_w;
    cv::max(w_levels[l], 1e-6, safe_w);
    cv::Mat own = v_levels[l] / RepeatChannels(safe_w, channels);
    own.setTo(cv::Scalar::all(0), w_levels[l] <= 1e-6);
    if (estimate.empty()) {
      estimate = own;
      continue;
    }
    cv::Mat up;
    cv::resize(estimate, up, own.size(), 0, 0, cv::INTER_LINEAR);
    const cv::Mat confidence = RepeatChannels(cv::min(w_levels[l] * 4.0, 1.0), channels);
    estimate = own.mul(confidence) + up.mul(cv::Scalar::all(1.0) - confidence);
  }
  return estimate;
}

}  // namespace avatar
