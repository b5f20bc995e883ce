#pragma once
// Identity embedding: faceplugin's fr_feature.onnx (ArcFace-style, MobileFaceNet-like, 512-d),
// run through OpenCV's dnn module. Input: the face warped to 112x112 by the ArcFace five-point
// similarity alignment, RGB, (x - 127.5) / 128. Output L2-normalised.
// Thread-safe: the cv::dnn::Net is guarded by a mutex.

#include <filesystem>
#include <memory>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/dnn.hpp>
#include <torch/torch.h>

#include "core/face/face_types.h"

namespace avatar::face {

// The hint that ends the load errors of the packaged face networks (identity, head pose).
inline constexpr char kReinstall[] = "; reinstall the models with scripts/setup";

// Reads an ONNX model with cv::dnn (OpenCV backend, CPU). Throws ModelLoad naming the file and
// scripts/setup when it is missing, truncated or not an ONNX model.
cv::dnn::Net LoadOnnxNet(const std::filesystem::path& file);

class IdentityNet {
 public:
  static constexpr int kInputSize = 112;
  static constexpr int kEmbeddingSize = 512;

  // Loads models/fr_feature.onnx from the data folder ("" = AVATAR_DATA_DIR, then
  // ~/.cache/avatar-studio). Throws ModelLoad (missing, truncated, foreign or wrong-shaped
  // file), naming the file and scripts/setup.
  explicit IdentityNet(const std::string& data_dir = {});
  // Loads this exact file (tests).
  static std::unique_ptr<IdentityNet> FromFile(const std::filesystem::path& onnx);
  ~IdentityNet();
  IdentityNet(const IdentityNet&) = delete;
  IdentityNet& operator=(const IdentityNet&) = delete;

  // The five alignment points taken from facemesh landmarks, image-left first: eye centres,
  // nose tip, mouth corners.
  static std::vector<cv::Point2f> FivePoints(const Landmarks& image_landmarks);
  // ArcFace's 112x112 template for those five points.
  static const std::vector<cv::Point2f>& Template();
  // Image -> 112x112 crop similarity transform for these landmarks.
  static cv::Matx23d AlignTransform(const Landmarks& image_landmarks);
  // The aligned 112x112 BGR8 crop.
  static cv::Mat AlignedCrop(const cv::Mat& bgr, const Landmarks& image_landmarks);

  // 512-d unit embedding of the face with these image landmarks (BGR8 image).
  std::vector<float> Embed(const cv::Mat& bgr, const Landmarks& image_landmarks) const;
  // 512-d unit embedding of an already aligned 112x112 BGR8 crop.
  std::vector<float> EmbedAligned(const cv::Mat& crop_bgr) const;
  // The raw network output for an aligned crop (not normalised).
  std::vector<float> RawOutput(const cv::Mat& crop_bgr) const;

  const std::filesystem::path& File() const;

 private:
  struct Impl;
  explicit IdentityNet(const std::filesystem::path& onnx, int);
  std::unique_ptr<Impl> impl_;
};

// A LibTorch copy of fr_feature for a differentiable identity term: the weights are read from
// the ONNX file through cv::dnn's layer parameters (fusion off), and the graph (Convolution with
// folded BN, PReLU, Add, Reshape) is replayed with torch ops in cv::dnn's layer order.
class IdentityTorch {
 public:
  // Throws ModelLoad like IdentityNet, and for a layer type outside the four above.
  static IdentityTorch FromFile(const std::filesystem::path& onnx);
  // models/fr_feature.onnx of the data folder.
  static IdentityTorch FromDataDir(const std::string& data_dir = {});

  // [N,3,112,112] float32 network input (RGB, (x-127.5)/128) -> [N,512] raw output
  // (not normalised). Differentiable with respect to the input.
  torch::Tensor Forward(const torch::Tensor& input) const;
  // Aligned 112x112 BGR8 crop -> the same input tensor IdentityNet builds.
  static torch::Tensor InputFromCrop(const cv::Mat& crop_bgr);
  int NumLayers() const { return static_cast<int>(layers_.size()); }

 private:
  struct Layer {
    enum Kind { kConv, kPRelu, kAdd, kReshape, kIdentity } kind;
    std::vector<int> inputs;  // indices into the layer list; -1 = network input
    torch::Tensor weight, bias;
    std::vector<int64_t> stride, pad;
  };
  std::vector<Layer> layers_;
};

}  // namespace avatar::face
