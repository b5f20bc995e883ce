#include "core/model/fusion_net.h"

#include <cmath>

#include "core/model/checkpoint.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace nn = torch::nn;

nn::Sequential DoubleConv(int64_t in, int64_t out) {
  return nn::Sequential(nn::Conv2d(nn::Conv2dOptions(in, out, 3).padding(1)),
                        nn::LeakyReLU(nn::LeakyReLUOptions().negative_slope(0.2)),
                        nn::Conv2d(nn::Conv2dOptions(out, out, 3).padding(1)),
                        nn::LeakyReLU(nn::LeakyReLUOptions().negative_slope(0.2)));
}

constexpr double kMaskBias = -2.0;

}  // namespace

torch::Tensor FusionInputFromBytes(const torch::Tensor& bytes, int64_t image_channels) {
  AVATAR_CHECK_INPUT(bytes.defined() && bytes.scalar_type() == torch::kUInt8 && bytes.dim() == 4 &&
                     image_channels >= 0 && image_channels <= bytes.size(1))
      << "fusion input bytes must be uint8 [B,C,H,W] with at least " << image_channels << " channels";
  torch::Tensor x = bytes.to(torch::kFloat32) / 255.0;
  if (image_channels == 0) return x;
  torch::Tensor images = x.slice(1, 0, image_channels) * 2.0 - 1.0;
  if (image_channels == x.size(1)) return images;
  return torch::cat({images, x.slice(1, image_channels)}, 1);
}

double FusionTurnDegrees(double d_yaw, double d_pitch) { return std::hypot(d_yaw, d_pitch); }

torch::Tensor FusionTurnFraction(const torch::Tensor& turn_degrees, int64_t batch) {
  AVATAR_CHECK_INPUT(turn_degrees.defined() && turn_degrees.numel() == batch)
      << "the fusion net with a turn input needs one turn per image (" << batch << "), got "
      << (turn_degrees.defined() ? turn_degrees.numel() : 0);
  const torch::Tensor t = turn_degrees.reshape({batch, 1, 1, 1}).to(torch::kFloat64).abs() / kFusionFullTurnDegrees;
  return t.nan_to_num(1.0, 1.0, 1.0).clamp(0.0, 1.0);
}

void FusionNetOptions::Validate() const {
  AVATAR_CHECK_OPTION(in_channels >= 1) << "the fusion net needs input channels, got " << in_channels;
  AVATAR_CHECK_OPTION(widths.size() >= 2) << "the fusion net needs at least two levels, got " << widths.size();
  for (int64_t w : widths) AVATAR_CHECK_OPTION(w >= 1 && w <= 1024) << "fusion net width " << w << " is outside 1..1024";
  AVATAR_CHECK_OPTION(!keep_warped || in_channels >= 8)
      << "keep_warped needs the warp weights in input channels 6 and 7, got " << in_channels << " channels";
  AVATAR_CHECK_OPTION(!turn || keep_warped) << "the fusion net's turn input opens the kept photo: it needs keep_warped";
  AVATAR_CHECK_OPTION(!turn_keeps_face || turn)
      << "turn_keeps_face (--turn-keeps-face) says what the turn opens: it needs the turn input (--turn)";
  AVATAR_CHECK_OPTION(std::isfinite(turn_open) && turn_open >= 0.0 && turn_open <= 1.0)
      << "turn_open (--turn-open) is a share of the turn's opening: it must be within 0..1, got " << turn_open;
  AVATAR_CHECK_OPTION(turn_open == 1.0 || turn)
      << "turn_open (--turn-open) scales what the turn opens: it needs the turn input (--turn)";
  AVATAR_CHECK_OPTION(!keep_eye_mouth || in_channels >= 10)
      << "keep_eye_mouth needs the eye/mouth region in input channel 9, got " << in_channels << " channels";
  AVATAR_CHECK_OPTION(!keep_face || in_channels >= 9)
      << "keep_face needs the face mesh's coverage in input channel 8, got " << in_channels << " channels";
  AVATAR_CHECK_OPTION(!gate_by_opacity || in_channels >= 11)
      << "gate_by_opacity needs the opacity in input channel 10, got " << in_channels << " channels";
}

FusionNetImpl::FusionNetImpl(const FusionNetOptions& options) : options_(options) {
  options_.Validate();
  const auto& w = options_.widths;
  down_ = register_module("down", nn::ModuleList());
  pool_ = register_module("pool", nn::ModuleList());
  up_ = register_module("up", nn::ModuleList());
  int64_t in = options_.in_channels + (options_.turn ? 1 : 0);
  for (size_t l = 0; l < w.size(); ++l) {
    down_->push_back(DoubleConv(in, w[l]));
    if (l + 1 < w.size()) pool_->push_back(nn::Conv2d(nn::Conv2dOptions(w[l], w[l], 3).stride(2).padding(1)));
    in = w[l];
  }
  for (size_t l = w.size() - 1; l-- > 0;) up_->push_back(DoubleConv(w[l + 1] + w[l], w[l]));
  head_ = register_module("head", nn::Conv2d(nn::Conv2dOptions(w[0], 4, 1)));
  torch::NoGradGuard no_grad;
  // The residual starts at exactly 0 (so the untrained net returns the composite) while the mask
  // starts partly open (sigmoid(-2) = 0.12), so the residual's weights get gradients at once.
  head_->weight.slice(0, 0, 3).zero_();
  head_->weight.slice(0, 3, 4).mul_(0.1);
  head_->bias.zero_();
  head_->bias[3].fill_(kMaskBias);
}

std::pair<torch::Tensor, torch::Tensor> FusionNetImpl::Heads(const torch::Tensor& x, const torch::Tensor& turn_degrees) {
  const int64_t levels = static_cast<int64_t>(options_.widths.size());
  const int64_t factor = int64_t{1} << (levels - 1);
  AVATAR_CHECK_INPUT(x.defined() && x.dim() == 4 && x.size(1) == options_.in_channels && x.size(2) % factor == 0 &&
                     x.size(3) % factor == 0 && x.size(2) > 0 && x.size(3) > 0)
      << "the fusion net takes [B," << options_.in_channels << ",H,W] with H and W divisible by " << factor
      << ", got " << x.sizes();
  std::vector<torch::Tensor> skips;
  torch::Tensor h = x;
  if (options_.turn) {
    const torch::Tensor plane = FusionTurnFraction(turn_degrees, x.size(0)).to(x.options());
    h = torch::cat({x, plane.expand({x.size(0), 1, x.size(2), x.size(3)})}, 1);
  }
  for (int64_t l = 0; l < levels; ++l) {
    h = down_[l]->as<nn::Sequential>()->forward(h);
    if (l + 1 < levels) {
      skips.push_back(h);
      h = pool_[l]->as<nn::Conv2d>()->forward(h);
    }
  }
  for (int64_t k = 0; k + 1 < levels; ++k) {
    const torch::Tensor& skip = skips[skips.size() - 1 - k];
    h = torch::nn::functional::interpolate(
        h, torch::nn::functional::InterpolateFuncOptions()
               .size(std::vector<int64_t>{skip.size(2), skip.size(3)})
               .mode(torch::kBilinear)
               .align_corners(false));
    h = up_[k]->as<nn::Sequential>()->forward(torch::cat({h, skip}, 1));
  }
  const torch::Tensor out = head_->forward(h);
  return {2.0 * torch::tanh(out.slice(1, 0, 3)), torch::sigmoid(out.slice(1, 3, 4))};
}

torch::Tensor FusionNetImpl::OpenTo(const torch::Tensor& x, const torch::Tensor& turn_degrees) const {
  torch::Tensor open = torch::ones_like(x.slice(1, 0, 1));
  if (options_.keep_warped) {
    if (!options_.turn) {
      open = 1.0 - std::get<0>(x.slice(1, 6, 8).max(1, /*keepdim=*/true)).clamp(0.0, 1.0);
    } else {
      const torch::Tensor held =
          1.0 - options_.turn_open * FusionTurnFraction(turn_degrees, x.size(0)).to(x.options());
      const torch::Tensor face = x.slice(1, 6, 7).clamp(0.0, 1.0);
      const torch::Tensor depth = x.slice(1, 7, 8).clamp(0.0, 1.0);
      open = options_.turn_keeps_face ? 1.0 - torch::max(face, depth * held) : 1.0 - torch::max(face, depth) * held;
    }
  }
  if (options_.gate_by_opacity) open = open * x.slice(1, 10, 11).clamp(0.0, 1.0);
  if (options_.keep_eye_mouth) open = open * (1.0 - x.slice(1, 9, 10).clamp(0.0, 1.0));
  if (options_.keep_face) open = open * (1.0 - x.slice(1, 8, 9).clamp(0.0, 1.0));
  return open;
}

torch::Tensor FusionNetImpl::forward(const torch::Tensor& x, const torch::Tensor& turn_degrees) {
  const auto [residual, mask] = Heads(x, turn_degrees);
  return x.slice(1, 0, 3) + OpenTo(x, turn_degrees) * mask * residual;
}

void CopyFusionWeights(const FusionNet& from, FusionNet& to) {
  AVATAR_CHECK_OPTION(from->options().widths == to->options().widths)
      << "fusion weights: the stored net's widths differ from this net's";
  torch::NoGradGuard no_grad;
  const auto src = from->named_parameters();
  for (auto& item : to->named_parameters()) {
    const torch::Tensor* stored = src.find(item.key());
    AVATAR_CHECK_OPTION(stored != nullptr) << "fusion weights: the stored net has no " << item.key();
    torch::Tensor& dst = item.value();
    if (stored->sizes() == dst.sizes()) {
      dst.copy_(*stored);
      continue;
    }
    const bool one_more_input = dst.dim() == 4 && stored->dim() == 4 && dst.size(0) == stored->size(0) &&
                                dst.size(1) == stored->size(1) + 1 && dst.size(2) == stored->size(2) &&
                                dst.size(3) == stored->size(3);
    AVATAR_CHECK_OPTION(one_more_input) << "fusion weights: " << item.key() << " is " << stored->sizes()
                                        << " in the stored net and " << dst.sizes() << " here";
    dst.zero_();
    dst.narrow(1, 0, stored->size(1)).copy_(*stored);
  }
}

int64_t FusionNetImpl::ParameterCount() const {
  int64_t n = 0;
  for (const auto& p : parameters()) n += p.numel();
  return n;
}

void SaveFusionNet(const std::filesystem::path& path, const FusionNet& net, const FusionNetInfo& info,
                   bool half_precision) {
  TensorArchive archive;
  archive.kind = "fusion-net";
  archive.meta = {{"step", info.step},
                  {"data_provenance", info.data_provenance},
                  {"in_channels", net->options().in_channels},
                  {"widths", net->options().widths},
                  {"keep_warped", net->options().keep_warped},
                  {"turn", net->options().turn},
                  {"turn_keeps_face", net->options().turn_keeps_face},
                  {"turn_open", net->options().turn_open},
                  {"keep_eye_mouth", net->options().keep_eye_mouth},
                  {"keep_face", net->options().keep_face},
                  {"gate_by_opacity", net->options().gate_by_opacity},
                  {"dtype", half_precision ? "float16" : "float32"}};
  torch::NoGradGuard no_grad;
  for (const auto& item : net->named_parameters()) {
    torch::Tensor t = item.value().detach().to(torch::kCPU, torch::kFloat32);
    AVATAR_CHECK_INPUT(torch::isfinite(t).all().item<bool>())
        << path.string() << ": not written: fusion net weight " << item.key() << " has a non-finite value";
    archive.tensors.emplace_back(item.key(), half_precision ? t.to(torch::kFloat16) : t.contiguous());
  }
  WriteTensorArchive(path, archive);
}

FusionNet LoadFusionNet(const std::filesystem::path& path, FusionNetInfo* info) {
  std::string fingerprint;
  const TensorArchive archive = ReadTensorArchive(path, "fusion-net", &fingerprint);
  FusionNetOptions options;
  try {
    options.in_channels = archive.meta.at("in_channels").get<int64_t>();
    options.widths = archive.meta.at("widths").get<std::vector<int64_t>>();
    options.keep_warped = archive.meta.contains("keep_warped") && archive.meta.at("keep_warped").get<bool>();
    options.turn = archive.meta.contains("turn") && archive.meta.at("turn").get<bool>();
    options.turn_keeps_face =
        archive.meta.contains("turn_keeps_face") && archive.meta.at("turn_keeps_face").get<bool>();
    options.turn_open = archive.meta.contains("turn_open") ? archive.meta.at("turn_open").get<double>() : 1.0;
    options.keep_eye_mouth = archive.meta.contains("keep_eye_mouth") && archive.meta.at("keep_eye_mouth").get<bool>();
    options.keep_face = archive.meta.contains("keep_face") && archive.meta.at("keep_face").get<bool>();
    options.gate_by_opacity =
        archive.meta.contains("gate_by_opacity") && archive.meta.at("gate_by_opacity").get<bool>();
    options.Validate();
  } catch (const std::exception& e) {
    throw ModelLoad(path.string() + ": the fusion net's shape is missing or invalid (" + e.what() +
                    "): the file is damaged; train or install it again");
  }
  FusionNet net(options);
  torch::NoGradGuard no_grad;
  for (auto& item : net->named_parameters()) {
    const torch::Tensor& stored = archive.Get(item.key(), path.string());
    if (stored.sizes() != item.value().sizes())
      throw ModelLoad(path.string() + ": fusion net weight " + item.key() + " has the wrong shape");
    item.value().copy_(stored.to(torch::kFloat32));
  }
  if (info != nullptr) {
    info->step = archive.meta.value("step", int64_t{0});
    info->data_provenance = archive.meta.value("data_provenance", std::string());
    info->fingerprint = fingerprint;
    info->options = options;
  }
  net->eval();
  return net;
}

void FusionExportOptions::Validate() const {
  AVATAR_CHECK_OPTION(std::isfinite(turn_open) && turn_open <= 1.0)
      << "--turn-open must be within 0..1 (or negative to keep the stored value), got " << turn_open;
}

FusionNetInfo ExportFusionNet(const std::filesystem::path& from, const std::filesystem::path& to,
                              const FusionExportOptions& options) {
  options.Validate();
  FusionNetInfo info;
  const FusionNet stored = LoadFusionNet(from, &info);
  FusionNetOptions net_options = info.options;
  if (options.turn_open >= 0.0) net_options.turn_open = options.turn_open;
  if (options.keep_eye_mouth) net_options.keep_eye_mouth = true;
  if (options.keep_face) net_options.keep_face = true;
  try {
    net_options.Validate();
  } catch (const InvalidOptions& e) {
    throw InvalidOptions(from.string() + ": " + e.what());
  }
  FusionNet exported(net_options);
  CopyFusionWeights(stored, exported);
  SaveFusionNet(to, exported, info, options.half_precision);
  FusionNetInfo written;
  LoadFusionNet(to, &written);
  return written;
}

}  // namespace avatar
