#include "core/face/blazeface.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/face/warp.h"
#include "core/util/error.h"

namespace avatar::face {

std::vector<Anchor> BlazeFaceAnchors(int input_size, const std::vector<int>& strides,
                                     const std::vector<int>& per_cell) {
  std::vector<Anchor> anchors;
  for (size_t s = 0; s < strides.size(); ++s) {
    const int grid = (input_size + strides[s] - 1) / strides[s];
    for (int y = 0; y < grid; ++y) {
      for (int x = 0; x < grid; ++x) {
        for (int k = 0; k < per_cell[s]; ++k) {
          anchors.push_back({(x + 0.5f) / grid, (y + 0.5f) / grid});
        }
      }
    }
  }
  return anchors;
}

float BoxIou(const cv::Rect2f& a, const cv::Rect2f& b) {
  const float inter = (a & b).area();
  const float uni = a.area() + b.area() - inter;
  return uni > 0.0f ? inter / uni : 0.0f;
}

std::vector<Detection> WeightedNms(std::vector<Detection> candidates, float iou_threshold) {
  std::sort(candidates.begin(), candidates.end(), [](const Detection& a, const Detection& b) { return a.score > b.score; });
  std::vector<Detection> out;
  std::vector<char> used(candidates.size(), 0);
  for (size_t i = 0; i < candidates.size(); ++i) {
    if (used[i]) continue;
    const Detection& best = candidates[i];
    double wsum = 0.0, x = 0.0, y = 0.0, w = 0.0, h = 0.0;
    std::array<cv::Point2d, 6> kp{};
    for (size_t j = i; j < candidates.size(); ++j) {
      if (used[j] || BoxIou(best.box, candidates[j].box) <= iou_threshold) continue;
      used[j] = 1;
      const Detection& c = candidates[j];
      const double s = c.score;
      wsum += s;
      x += s * c.box.x;
      y += s * c.box.y;
      w += s * c.box.width;
      h += s * c.box.height;
      for (size_t k = 0; k < kp.size(); ++k) kp[k] += s * cv::Point2d(c.keypoints[k]);
    }
    Detection merged = best;
    if (wsum > 0.0) {
      merged.box = cv::Rect2f(static_cast<float>(x / wsum), static_cast<float>(y / wsum), static_cast<float>(w / wsum),
                              static_cast<float>(h / wsum));
      for (size_t k = 0; k < kp.size(); ++k) merged.keypoints[k] = cv::Point2f(kp[k] / wsum);
    }
    out.push_back(merged);
  }
  return out;
}

BlazeFace::BlazeFace(io::TfjsGraph graph, bool front) : graph_(std::move(graph)) {
  input_size_ = front ? 128 : 256;
  const auto shape = graph_.InputShape(graph_.InputNames().at(0));
  AVATAR_CHECK_AS(ModelLoad, shape.size() == 4 && shape[1] == input_size_ && shape[2] == input_size_)
      << "model " << graph_.Path().string() << " is not a " << input_size_ << " px BlazeFace model";
  anchors_ = front ? BlazeFaceAnchors(128, {8, 16}, {2, 6}) : BlazeFaceAnchors(256, {16, 32}, {2, 6});
}

std::vector<Detection> BlazeFace::DetectInput(const torch::Tensor& input, float min_score) const {
  // Outputs: scores of the fine grid [1,512,1], of the coarse grid [1,384,1], and the 16
  // regressors (box centre offset, size, 6 keypoints; input pixels relative to the anchor).
  const auto out = graph_.Run(input, {"Identity", "Identity_1", "Identity_2", "Identity_3"});
  torch::Tensor scores, regs;
  // The graph names do not say which grid is which; the anchor counts do.
  if (out[0].size(1) == 512) {
    scores = torch::cat({out[0], out[1]}, 1).reshape({-1});
    regs = torch::cat({out[2], out[3]}, 1).reshape({-1, 16});
  } else {
    scores = torch::cat({out[1], out[0]}, 1).reshape({-1});
    regs = torch::cat({out[3], out[2]}, 1).reshape({-1, 16});
  }
  AVATAR_CHECK_AS(ModelLoad, scores.size(0) == static_cast<int64_t>(anchors_.size()))
      << "model " << graph_.Path().string() << " gives " << scores.size(0) << " anchors, expected " << anchors_.size();
  const auto prob = torch::sigmoid(scores.clamp(-100.0, 100.0)).contiguous();
  const auto reg = regs.contiguous();
  const float* p = prob.data_ptr<float>();
  const float* r = reg.data_ptr<float>();
  const float s = static_cast<float>(input_size_);
  std::vector<Detection> dets;
  for (size_t i = 0; i < anchors_.size(); ++i) {
    if (!(p[i] >= min_score)) continue;
    const float* v = r + i * 16;
    const float cx = anchors_[i].x * s + v[0];
    const float cy = anchors_[i].y * s + v[1];
    const float w = v[2];
    const float h = v[3];
    Detection d;
    d.score = p[i];
    d.box = cv::Rect2f(cx - w / 2, cy - h / 2, w, h);
    for (int k = 0; k < 6; ++k) d.keypoints[k] = {anchors_[i].x * s + v[4 + 2 * k], anchors_[i].y * s + v[5 + 2 * k]};
    if (w > 0 && h > 0 && std::isfinite(cx) && std::isfinite(cy)) dets.push_back(d);
  }
  return dets;
}

std::vector<Detection> BlazeFace::DetectRegion(const cv::Mat& bgr, const cv::Rect& region, float min_score) const {
  const int side = std::max(region.width, region.height);
  const double scale = static_cast<double>(input_size_) / side;
  // Region pixel -> input pixel: centred letterbox.
  const double ox = (side - region.width) / 2.0 - region.x;
  const double oy = (side - region.height) / 2.0 - region.y;
  const cv::Matx23d m(scale, 0, scale * ox, 0, scale, scale * oy);
  const torch::Tensor input = WarpToTensor(bgr, m, input_size_, input_size_, -1.0f, 1.0f);
  std::vector<Detection> dets = DetectInput(input, min_score);
  for (auto& d : dets) {
    d.box = cv::Rect2f(static_cast<float>(d.box.x / scale - ox), static_cast<float>(d.box.y / scale - oy),
                       static_cast<float>(d.box.width / scale), static_cast<float>(d.box.height / scale));
    for (auto& k : d.keypoints) k = cv::Point2f(static_cast<float>(k.x / scale - ox), static_cast<float>(k.y / scale - oy));
  }
  return dets;
}

}  // namespace avatar::face
