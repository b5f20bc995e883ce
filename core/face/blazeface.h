#pragma once
// BlazeFace face detection (MediaPipe short-range "front" and full-range "back" models) on the
// TF.js runtime: anchors, box/keypoint decoding and weighted non-maximum suppression.

#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/io/tfjs_graph.h"

namespace avatar::face {

// One BlazeFace anchor in normalised [0,1] input coordinates (fixed size 1x1, as MediaPipe uses).
struct Anchor {
  float x = 0.0f;
  float y = 0.0f;
};

// The SSD anchor grid of a BlazeFace model: for each stride, a (size/stride)^2 grid of cells
// with `per_cell` anchors at the cell centre. Front (128 px): strides 8 (2 per cell) and 16
// (6 per cell); back (256 px): strides 16 (2) and 32 (6). Both give 896 anchors.
std::vector<Anchor> BlazeFaceAnchors(int input_size, const std::vector<int>& strides,
                                     const std::vector<int>& per_cell);

// Weighted NMS (MediaPipe's WEIGHTED mode): candidates overlapping the best remaining one by
// more than `iou_threshold` are merged into it, coordinates averaged with score weights; the
// merged score is the best one. Output sorted by score, highest first.
std::vector<Detection> WeightedNms(std::vector<Detection> candidates, float iou_threshold);

// Intersection over union of two boxes (0 for empty boxes).
float BoxIou(const cv::Rect2f& a, const cv::Rect2f& b);

class BlazeFace {
 public:
  // `front` selects the 128 px short-range model, else the 256 px full-range one.
  BlazeFace(io::TfjsGraph graph, bool front);

  int InputSize() const { return input_size_; }

  // Detects faces in a square RGB input already scaled to InputSize(): `input` [1,S,S,3] in
  // [-1,1]. Returns detections in input pixels with score >= min_score (before NMS).
  std::vector<Detection> DetectInput(const torch::Tensor& input, float min_score) const;

  // Detects faces in a BGR image region: the region is letterboxed (centred, black borders)
  // into the model input; results are mapped back to image pixels. Before NMS.
  std::vector<Detection> DetectRegion(const cv::Mat& bgr, const cv::Rect& region, float min_score) const;

 private:
  io::TfjsGraph graph_;
  int input_size_ = 128;
  std::vector<Anchor> anchors_;
};

}  // namespace avatar::face
