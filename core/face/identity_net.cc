#include "core/face/identity_net.h"

#include <cmath>
#include <fstream>
#include <mutex>

#include <map>

#include <opencv2/dnn.hpp>
#include <opencv2/dnn/all_layers.hpp>
#include <opencv2/imgproc.hpp>

#include "core/face/face_geometry.h"
#include "core/face/warp.h"
#include "core/io/data_paths.h"
#include "core/util/error.h"

namespace avatar::face {
namespace {

// ONNX files are protobuf messages; a file that does not start like one (field 1 ir_version,
// varint) is foreign. cv::dnn reports such files with a generic parse error, so check first.
void CheckLooksLikeOnnx(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  char head[2] = {0, 0};
  in.read(head, 2);
  AVATAR_CHECK_AS(ModelLoad, in.gcount() == 2 && head[0] == 0x08)
      << "model " << file.string() << " is not an ONNX file" << kReinstall;
}

}  // namespace

cv::dnn::Net LoadOnnxNet(const std::filesystem::path& file) {
  std::error_code ec;
  AVATAR_CHECK_AS(ModelLoad, std::filesystem::is_regular_file(file, ec))
      << "model " << file.string() << " is missing" << kReinstall;
  CheckLooksLikeOnnx(file);
  cv::dnn::Net net;
  try {
    net = cv::dnn::readNetFromONNX(file.string());
  } catch (const cv::Exception& e) {
    throw ModelLoad("model " + file.string() + " cannot be read (truncated or not an ONNX model: " + e.msg + ")" +
                    kReinstall);
  }
  AVATAR_CHECK_AS(ModelLoad, !net.empty()) << "model " << file.string() << " has no layers" << kReinstall;
  net.setPreferableBackend(cv::dnn::DNN_BACKEND_OPENCV);
  net.setPreferableTarget(cv::dnn::DNN_TARGET_CPU);
  return net;
}

struct IdentityNet::Impl {
  std::filesystem::path file;
  mutable std::mutex mutex;
  mutable cv::dnn::Net net;
};

IdentityNet::IdentityNet(const std::string& data_dir)
    : IdentityNet(DataPaths::Resolve(data_dir).Path("models/fr_feature.onnx"), 0) {}

std::unique_ptr<IdentityNet> IdentityNet::FromFile(const std::filesystem::path& onnx) {
  return std::unique_ptr<IdentityNet>(new IdentityNet(onnx, 0));
}

IdentityNet::IdentityNet(const std::filesystem::path& onnx, int) : impl_(std::make_unique<Impl>()) {
  impl_->file = onnx;
  impl_->net = LoadOnnxNet(onnx);
  // One trial run checks the graph really is the 112 -> 512 embedding.
  std::vector<float> out;
  try {
    out = RawOutput(cv::Mat(kInputSize, kInputSize, CV_8UC3, cv::Scalar(128, 128, 128)));
  } catch (const cv::Exception& e) {
    throw ModelLoad("model " + onnx.string() + " does not run on a 1x3x112x112 input (" + e.msg + ")" + kReinstall);
  }
  AVATAR_CHECK_AS(ModelLoad, out.size() == static_cast<size_t>(kEmbeddingSize))
      << "model " << onnx.string() << " gives " << out.size() << " outputs, expected " << kEmbeddingSize
      << " (not fr_feature.onnx?)" << kReinstall;
}

IdentityNet::~IdentityNet() = default;

const std::filesystem::path& IdentityNet::File() const { return impl_->file; }

const std::vector<cv::Point2f>& IdentityNet::Template() {
  static const std::vector<cv::Point2f> t = {
      {38.2946f, 51.6963f}, {73.5318f, 51.5014f}, {56.0252f, 71.7366f}, {41.5493f, 92.3655f}, {70.7299f, 92.2041f}};
  return t;
}

std::vector<cv::Point2f> IdentityNet::FivePoints(const Landmarks& lm) {
  AVATAR_CHECK_INPUT(lm.points.size() == static_cast<size_t>(kMeshPoints)) << "identity alignment needs 468 landmarks";
  auto p2 = [&](int i) { return cv::Point2f(lm.points[i].x, lm.points[i].y); };
  // Subject's right eye / mouth corner appear on the image's left.
  return {RegionCentre(lm, mesh_index::RightEye()), RegionCentre(lm, mesh_index::LeftEye()), p2(mesh_index::kNoseTip),
          p2(mesh_index::kMouthRight), p2(mesh_index::kMouthLeft)};
}

cv::Matx23d IdentityNet::AlignTransform(const Landmarks& lm) { return SimilarityFromPoints(FivePoints(lm), Template()); }

cv::Mat IdentityNet::AlignedCrop(const cv::Mat& bgr, const Landmarks& lm) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "identity embedding needs an 8-bit BGR image";
  // Pre-filters strong downscaling (area), black outside the image.
  return WarpImage(bgr, AlignTransform(lm), kInputSize, kInputSize);
}

std::vector<float> IdentityNet::RawOutput(const cv::Mat& crop) const {
  AVATAR_CHECK_INPUT(crop.type() == CV_8UC3 && crop.rows == kInputSize && crop.cols == kInputSize)
      << "the aligned identity crop must be 112x112 BGR8";
  // RGB, (x - 127.5) / 128.
  const cv::Mat blob = cv::dnn::blobFromImage(crop, 1.0 / 128.0, cv::Size(kInputSize, kInputSize),
                                              cv::Scalar(127.5, 127.5, 127.5), /*swapRB=*/true, /*crop=*/false, CV_32F);
  cv::Mat out;
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    impl_->net.setInput(blob);
    out = impl_->net.forward().clone();
  }
  const float* p = out.ptr<float>();
  return std::vector<float>(p, p + out.total());
}

std::vector<float> IdentityNet::EmbedAligned(const cv::Mat& crop) const {
  std::vector<float> e = RawOutput(crop);
  double n = 0;
  for (float v : e) n += static_cast<double>(v) * v;
  n = std::sqrt(n);
  AVATAR_CHECK(std::isfinite(n) && n > 1e-12) << "identity embedding is zero or not finite";
  for (float& v : e) v = static_cast<float>(v / n);
  return e;
}

std::vector<float> IdentityNet::Embed(const cv::Mat& bgr, const Landmarks& lm) const {
  return EmbedAligned(AlignedCrop(bgr, lm));
}

namespace {

torch::Tensor BlobToTensor(const cv::Mat& blob) {
  std::vector<int64_t> shape;
  for (int d = 0; d < blob.dims; ++d) shape.push_back(blob.size[d]);
  AVATAR_CHECK(blob.type() == CV_32F && blob.isContinuous()) << "unexpected cv::dnn blob type";
  return torch::from_blob(const_cast<float*>(blob.ptr<float>()), shape, torch::kFloat32).clone();
}

}  // namespace

IdentityTorch IdentityTorch::FromDataDir(const std::string& data_dir) {
  return FromFile(DataPaths::Resolve(data_dir).Path("models/fr_feature.onnx"));
}

IdentityTorch IdentityTorch::FromFile(const std::filesystem::path& onnx) {
  cv::dnn::Net net = LoadOnnxNet(onnx);
  net.enableFusion(false);
  IdentityTorch out;
  std::map<std::string, int> index;  // cv::dnn layer name -> our layer index
  const std::vector<std::string> names = net.getLayerNames();
  for (const std::string& name : names) {
    const int id = net.getLayerId(name);
    const cv::Ptr<cv::dnn::Layer> layer = net.getLayer(id);
    Layer l;
    for (const auto& in : net.getLayerInputs(id)) {
      const auto it = index.find(in->name);
      l.inputs.push_back(it == index.end() ? -1 : it->second);
    }
    const std::string& type = layer->type;
    auto fail = [&](const std::string& what) {
      return ModelLoad("model " + onnx.string() + ": layer '" + name + "' (" + type + "): " + what + kReinstall);
    };
    if (type == "Convolution") {
      const auto conv = layer.dynamicCast<cv::dnn::BaseConvolutionLayer>();
      if (conv.empty() || layer->blobs.empty() || conv->kernel_size.size() != 2) throw fail("not a 2-D convolution");
      for (size_t d : conv->dilations) {
        if (d != 1) throw fail("dilated convolutions are not supported");
      }
      if (conv->pads_begin != conv->pads_end) throw fail("asymmetric padding is not supported");
      l.kind = Layer::kConv;
      l.weight = BlobToTensor(layer->blobs[0]);
      if (layer->blobs.size() > 1) l.bias = BlobToTensor(layer->blobs[1]).reshape({-1});
      for (size_t s : conv->strides) l.stride.push_back(static_cast<int64_t>(s));
      for (size_t p : conv->pads_begin) l.pad.push_back(static_cast<int64_t>(p));
    } else if (type == "PReLU") {
      if (layer->blobs.empty()) throw fail("no slopes");
      l.kind = Layer::kPRelu;
      l.weight = BlobToTensor(layer->blobs[0]).reshape({-1});
    } else if (type == "Eltwise") {
      l.kind = Layer::kAdd;  // the ONNX Add nodes (cv::dnn's default Eltwise operation is a sum)
      if (l.inputs.size() < 2) throw fail("an Add with fewer than two inputs");
    } else if (type == "Reshape" || type == "Flatten") {
      l.kind = Layer::kReshape;
    } else if (type == "Identity") {
      l.kind = Layer::kIdentity;
    } else {
      throw fail("unsupported layer type for the LibTorch copy");
    }
    if (l.inputs.empty()) l.inputs.push_back(-1);
    index[name] = static_cast<int>(out.layers_.size());
    out.layers_.push_back(std::move(l));
  }
  AVATAR_CHECK_AS(ModelLoad, !out.layers_.empty()) << "model " << onnx.string() << " has no layers" << kReinstall;
  return out;
}

torch::Tensor IdentityTorch::InputFromCrop(const cv::Mat& crop) {
  AVATAR_CHECK_INPUT(crop.type() == CV_8UC3 && crop.rows == IdentityNet::kInputSize &&
                     crop.cols == IdentityNet::kInputSize)
      << "the aligned identity crop must be 112x112 BGR8";
  const cv::Mat blob = cv::dnn::blobFromImage(crop, 1.0 / 128.0, crop.size(), cv::Scalar(127.5, 127.5, 127.5), true,
                                              false, CV_32F);
  return BlobToTensor(blob);
}

torch::Tensor IdentityTorch::Forward(const torch::Tensor& input) const {
  AVATAR_CHECK_INPUT(input.dim() == 4 && input.size(1) == 3 && input.size(2) == IdentityNet::kInputSize &&
                     input.size(3) == IdentityNet::kInputSize)
      << "identity input must be [N,3,112,112], got " << input.sizes();
  std::vector<torch::Tensor> values(layers_.size());
  auto get = [&](int i) { return i < 0 ? input : values[i]; };
  for (size_t k = 0; k < layers_.size(); ++k) {
    const Layer& l = layers_[k];
    const torch::Tensor x = get(l.inputs[0]);
    switch (l.kind) {
      case Layer::kConv: {
        const int64_t groups = x.size(1) / l.weight.size(1);
        values[k] = torch::conv2d(x, l.weight, l.bias, l.stride, l.pad, {1, 1}, groups);
        break;
      }
      case Layer::kPRelu:
        values[k] = torch::prelu(x, l.weight);
        break;
      case Layer::kAdd: {
        torch::Tensor sum = x;
        for (size_t i = 1; i < l.inputs.size(); ++i) sum = sum + get(l.inputs[i]);
        values[k] = sum;
        break;
      }
      case Layer::kReshape:
        values[k] = x.reshape({x.size(0), -1});
        break;
      case Layer::kIdentity:
        values[k] = x;
        break;
    }
  }
  return values.back();
}

}  // namespace avatar::face
