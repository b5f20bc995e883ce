#include "core/model/mobilenet_v2.h"

#include <algorithm>
#include <map>
#include <set>

#include "core/io/data_paths.h"
#include "core/util/error.h"

namespace avatar {
namespace {

const char* const kReinstall = "; reinstall the models with scripts/setup";

// Keras MobileNetV2 alpha 1.0 after expanded_conv: {expansion, channels, repeats, first stride}.
struct StageSpec {
  int64_t expand, channels, repeats, stride;
};
constexpr StageSpec kStages[] = {{6, 24, 2, 2}, {6, 32, 3, 2},  {6, 64, 4, 2},
                                 {6, 96, 3, 1}, {6, 160, 3, 2}, {6, 320, 1, 1}};

[[noreturn]] void Fail(const io::KerasLayersModel& model, const std::string& what) {
  throw ModelLoad("model " + model.path.string() + ": " + what + " (not nsfwjs's MobileNetV2?)" + kReinstall);
}

const io::KerasLayer& Layer(const io::KerasLayersModel& model, const std::string& name, const std::string& cls) {
  const io::KerasLayer* l = model.Find(name);
  if (l == nullptr) Fail(model, "layer '" + name + "' missing");
  if (l->class_name != cls) Fail(model, "layer '" + name + "' is a " + l->class_name + ", expected " + cls);
  return *l;
}

std::vector<int64_t> Ints(const nlohmann::json& j) {
  std::vector<int64_t> v;
  for (const auto& e : j) v.push_back(e.get<int64_t>());
  return v;
}

}  // namespace

void MobileNetV2Options::Validate() const {
  AVATAR_CHECK_OPTION(last_block >= 0 && last_block <= 16)
      << "mobilenet_v2 last_block must be in 0..16, got " << last_block;
  AVATAR_CHECK_OPTION(bn_epsilon > 0.0) << "mobilenet_v2 bn_epsilon must be > 0, got " << bn_epsilon;
  AVATAR_CHECK_OPTION(in_channels > 0 && in_channels % 3 == 0)
      << "mobilenet_v2 in_channels must be a multiple of 3, got " << in_channels;
}

MobileNetV2Impl::ConvBn MobileNetV2Impl::MakeConvBn(const std::string& conv_name, const std::string& bn_name,
                                                    int64_t in, int64_t out, int64_t kernel, int64_t stride,
                                                    bool depthwise) {
  ConvBn c;
  c.conv_name = conv_name;
  c.bn_name = bn_name;
  c.stride = stride;
  c.depthwise = depthwise;
  auto o = torch::nn::Conv2dOptions(in, out, kernel).stride(stride).bias(false);
  if (depthwise) o.groups(in);
  c.conv = register_module(conv_name, torch::nn::Conv2d(o));
  c.bn = register_module(bn_name, torch::nn::BatchNorm2d(torch::nn::BatchNorm2dOptions(out).eps(options_.bn_epsilon)));
  const int64_t p = kernel / 2;
  // Keras: 'same' for stride 1; an explicit ZeroPadding2D ((0,1),(0,1)) before stride 2.
  c.pad = stride == 1 ? std::vector<int64_t>{p, p, p, p} : std::vector<int64_t>{0, 1, 0, 1};
  return c;
}

MobileNetV2Impl::MobileNetV2Impl(const MobileNetV2Options& options) : options_(options) {
  options_.Validate();
  stem_ = MakeConvBn("Conv1", "bn_Conv1", options_.in_channels, 32, 3, 2, false);
  Block b0;
  b0.index = 0;
  b0.prefix = "expanded_conv";
  b0.in = 32;
  b0.out = 16;
  b0.expand = 32;
  b0.depthwise = MakeConvBn("expanded_conv_depthwise", "expanded_conv_depthwise_BN", 32, 32, 3, 1, true);
  b0.project = MakeConvBn("expanded_conv_project", "expanded_conv_project_BN", 32, 16, 1, 1, false);
  blocks_.push_back(std::move(b0));
  int index = 1;
  int64_t in = 16;
  for (const StageSpec& s : kStages) {
    for (int64_t r = 0; r < s.repeats && index <= options_.last_block; ++r, ++index) {
      Block b;
      b.index = index;
      b.prefix = "block_" + std::to_string(index);
      b.in = in;
      b.out = s.channels;
      b.expand = in * s.expand;
      b.stride = r == 0 ? s.stride : 1;
      b.residual = b.stride == 1 && b.in == b.out;
      const std::string& p = b.prefix;
      b.expand_conv = MakeConvBn(p + "_expand", p + "_expand_BN", b.in, b.expand, 1, 1, false);
      b.depthwise = MakeConvBn(p + "_depthwise", p + "_depthwise_BN", b.expand, b.expand, 3, b.stride, true);
      b.project = MakeConvBn(p + "_project", p + "_project_BN", b.expand, b.out, 1, 1, false);
      blocks_.push_back(std::move(b));
      in = s.channels;
    }
  }
}

torch::Tensor MobileNetV2Impl::Apply(const ConvBn& c, const torch::Tensor& x) const {
  const auto& p = c.pad;
  const bool symmetric = p[0] == p[1] && p[1] == p[2] && p[2] == p[3];
  torch::Tensor in = symmetric ? x : torch::constant_pad_nd(x, p, 0.0);
  const int64_t conv_pad = symmetric ? p[0] : 0;
  torch::Tensor y = torch::conv2d(in, c.conv->weight, {}, {c.stride, c.stride}, {conv_pad, conv_pad}, {1, 1},
                                  c.depthwise ? c.conv->weight.size(0) : 1);
  // Frozen statistics, also in train(): the ImageNet features are kept as trained.
  return torch::batch_norm(y, c.bn->weight, c.bn->bias, c.bn->running_mean, c.bn->running_var,
                           /*training=*/false, 0.0, c.bn->options.eps(), /*cudnn_enabled=*/true);
}

std::vector<torch::Tensor> MobileNetV2Impl::Features(const torch::Tensor& x,
                                                     const std::vector<std::string>& taps) const {
  AVATAR_CHECK_INPUT(x.dim() == 4 && x.size(1) == options_.in_channels && x.size(2) >= 32 && x.size(3) >= 32)
      << "MobileNetV2 expects [B," << options_.in_channels << ",H,W] with H, W >= 32, got " << x.sizes();
  const auto names = TapNames();
  const std::set<std::string> known(names.begin(), names.end());
  for (const auto& t : taps) {
    AVATAR_CHECK_INPUT(known.count(t) > 0)
        << "MobileNetV2 has no tap '" << t << "' (built up to block_" << options_.last_block << ")";
  }
  if (taps.empty()) return {};
  std::map<std::string, torch::Tensor> found;
  const std::set<std::string> wanted(taps.begin(), taps.end());
  auto keep = [&](const std::string& name, const torch::Tensor& t) {
    if (wanted.count(name) > 0) found[name] = t;
    return found.size() == wanted.size();
  };
  auto relu6 = [](const torch::Tensor& t) { return torch::hardtanh(t, 0.0, 6.0); };
  torch::Tensor h = relu6(Apply(stem_, x));
  const bool done = keep("Conv1_relu", h);
  for (size_t i = 0; i < blocks_.size() && !done; ++i) {
    const Block& b = blocks_[i];
    torch::Tensor e = h;
    if (b.index > 0) {
      e = relu6(Apply(b.expand_conv, h));
      if (keep(b.prefix + "_expand_relu", e)) break;
    }
    torch::Tensor d = relu6(Apply(b.depthwise, e));
    if (keep(b.prefix + "_depthwise_relu", d)) break;
    torch::Tensor p = Apply(b.project, d);
    if (keep(b.prefix + "_project_BN", p)) break;
    h = b.residual ? h + p : p;
    if (b.residual && keep(b.prefix + "_add", h)) break;
  }
  std::vector<torch::Tensor> out;
  for (const auto& t : taps) out.push_back(found.at(t));
  return out;
}

torch::Tensor MobileNetV2Impl::forward(const torch::Tensor& x) const {
  const Block& last = blocks_.back();
  return Features(x, {last.residual ? last.prefix + "_add" : last.prefix + "_project_BN"})[0];
}

std::vector<std::string> MobileNetV2Impl::TapNames() const {
  std::vector<std::string> names = {"Conv1_relu"};
  for (const Block& b : blocks_) {
    if (b.index > 0) names.push_back(b.prefix + "_expand_relu");
    names.push_back(b.prefix + "_depthwise_relu");
    names.push_back(b.prefix + "_project_BN");
    if (b.residual) names.push_back(b.prefix + "_add");
  }
  return names;
}

int64_t MobileNetV2Impl::TapChannels(const std::string& tap) const {
  if (tap == "Conv1_relu") return 32;
  for (const Block& b : blocks_) {
    if (tap == b.prefix + "_expand_relu" || tap == b.prefix + "_depthwise_relu") return b.expand;
    if (tap == b.prefix + "_project_BN" || tap == b.prefix + "_add") return b.out;
  }
  throw InvalidInput("MobileNetV2 has no tap '" + tap + "'");
}

int64_t MobileNetV2Impl::TapStride(const std::string& tap) const {
  if (tap == "Conv1_relu") return 2;
  int64_t stride = 2;
  for (const Block& b : blocks_) {
    if (tap == b.prefix + "_expand_relu") return stride;
    stride *= b.stride;
    if (tap == b.prefix + "_depthwise_relu" || tap == b.prefix + "_project_BN" || tap == b.prefix + "_add") {
      return stride;
    }
  }
  throw InvalidInput("MobileNetV2 has no tap '" + tap + "'");
}

void MobileNetV2Impl::Freeze() {
  for (auto& p : parameters()) p.set_requires_grad(false);
}

void MobileNetV2Impl::LoadConvBn(const io::KerasLayersModel& model, ConvBn& c) {
  const std::string cls = c.depthwise ? "DepthwiseConv2D" : "Conv2D";
  const io::KerasLayer& conv = Layer(model, c.conv_name, cls);
  const auto& cfg = conv.config;
  const auto strides = Ints(cfg.value("strides", nlohmann::json::array({1, 1})));
  if (strides != std::vector<int64_t>{c.stride, c.stride}) Fail(model, "layer '" + c.conv_name + "' has other strides");
  if (cfg.value("use_bias", false)) Fail(model, "layer '" + c.conv_name + "' has a bias");
  if (c.depthwise && cfg.value("depth_multiplier", 1) != 1)
    Fail(model, "layer '" + c.conv_name + "' depth_multiplier != 1");
  const auto kernel = Ints(cfg.at("kernel_size"));
  const int64_t k = c.conv->weight.size(2);
  if (kernel != std::vector<int64_t>{k, k}) Fail(model, "layer '" + c.conv_name + "' has another kernel size");
  const std::string padding = cfg.value("padding", "valid");
  if (padding == "same") {
    if (c.stride != 1) Fail(model, "layer '" + c.conv_name + "': 'same' padding with stride 2 is not supported");
    c.pad = {k / 2, k / 2, k / 2, k / 2};
  } else if (padding == "valid") {
    c.pad = {0, 0, 0, 0};
    if (!conv.inbound.empty()) {
      const io::KerasLayer* in = model.Find(conv.inbound[0]);
      if (in != nullptr && in->class_name == "ZeroPadding2D") {
        // Keras: ((top, bottom), (left, right)); torch pad order: left, right, top, bottom.
        const auto& p = in->config.at("padding");
        c.pad = {p.at(1).at(0).get<int64_t>(), p.at(1).at(1).get<int64_t>(), p.at(0).at(0).get<int64_t>(),
                 p.at(0).at(1).get<int64_t>()};
      }
    }
  } else {
    Fail(model, "layer '" + c.conv_name + "' has padding '" + padding + "'");
  }
  const torch::Tensor w = model.Weight(c.conv_name + (c.depthwise ? "/depthwise_kernel" : "/kernel"));
  torch::Tensor oihw;
  if (c.depthwise) {
    // [kh,kw,in,1] -> [in,1,kh,kw]
    if (w.dim() != 4 || w.size(3) != 1) Fail(model, "weight of '" + c.conv_name + "' has shape " + c10::str(w.sizes()));
    oihw = w.permute({2, 3, 0, 1});
  } else {
    // HWIO -> OIHW
    if (w.dim() != 4) Fail(model, "weight of '" + c.conv_name + "' has shape " + c10::str(w.sizes()));
    oihw = w.permute({3, 2, 0, 1});
  }
  const int64_t groups = c.conv->weight.size(1) / std::max<int64_t>(oihw.size(1), 1);
  if (!c.depthwise && groups > 1 && oihw.size(1) * groups == c.conv->weight.size(1)) {
    oihw = oihw.repeat({1, groups, 1, 1}) / static_cast<double>(groups);  // k*3-channel input, see header
  }
  if (oihw.sizes() != c.conv->weight.sizes()) {
    Fail(model, "weight of '" + c.conv_name + "' has shape " + c10::str(w.sizes()) + ", expected OIHW " +
                    c10::str(c.conv->weight.sizes()));
  }
  const io::KerasLayer& bn = Layer(model, c.bn_name, "BatchNormalization");
  if (!bn.config.value("center", true) || !bn.config.value("scale", true)) {
    Fail(model, "layer '" + c.bn_name + "' lacks beta or gamma");
  }
  const double eps = bn.config.value("epsilon", options_.bn_epsilon);
  c.bn->options.eps(eps);
  torch::NoGradGuard no_grad;
  c.conv->weight.copy_(oihw.contiguous());
  const int64_t n = c.bn->weight.size(0);
  auto vec = [&](const std::string& what, torch::Tensor& dst) {
    const torch::Tensor& v = model.Weight(c.bn_name + "/" + what);
    if (v.dim() != 1 || v.size(0) != n) Fail(model, "weight '" + c.bn_name + "/" + what + "' has the wrong size");
    dst.copy_(v);
  };
  vec("gamma", c.bn->weight);
  vec("beta", c.bn->bias);
  vec("moving_mean", c.bn->running_mean);
  vec("moving_variance", c.bn->running_var);
}

void MobileNetV2Impl::LoadKeras(const io::KerasLayersModel& model) {
  LoadConvBn(model, stem_);
  auto check_relu = [&](const std::string& name) {
    const io::KerasLayer& l = Layer(model, name, "ReLU");
    if (!l.config.contains("max_value") || l.config["max_value"].get<double>() != 6.0) {
      Fail(model, "layer '" + name + "' is not ReLU6");
    }
  };
  check_relu("Conv1_relu");
  for (Block& b : blocks_) {
    if (b.index > 0) {
      LoadConvBn(model, b.expand_conv);
      check_relu(b.prefix + "_expand_relu");
    }
    LoadConvBn(model, b.depthwise);
    check_relu(b.prefix + "_depthwise_relu");
    LoadConvBn(model, b.project);
    if (b.residual) Layer(model, b.prefix + "_add", "Add");
  }
  options_.bn_epsilon = stem_.bn->options.eps();
}

const std::vector<std::string>& MobileNetV2EncoderImpl::StageTaps() {
  static const std::vector<std::string> taps = {"block_2_add", "block_5_add", "block_12_add", "block_16_project_BN"};
  return taps;
}

MobileNetV2EncoderImpl::MobileNetV2EncoderImpl(int64_t in_channels, int64_t decoder_dim) : decoder_dim_(decoder_dim) {
  AVATAR_CHECK_OPTION(decoder_dim > 0) << "decoder_dim must be > 0, got " << decoder_dim;
  MobileNetV2Options o;
  o.last_block = 16;
  o.in_channels = static_cast<int>(in_channels);
  backbone_ = register_module("backbone", MobileNetV2(o));
  for (size_t s = 0; s < StageTaps().size(); ++s) {
    const int64_t c = backbone_->TapChannels(StageTaps()[s]);
    head_linears_.push_back(register_module("head_linear" + std::to_string(s),
                                            torch::nn::Conv2d(torch::nn::Conv2dOptions(c, decoder_dim, 1))));
  }
  fuse_ = register_module("head_fuse",
                          torch::nn::Conv2d(torch::nn::Conv2dOptions(4 * decoder_dim, decoder_dim, 1).bias(false)));
}

void MobileNetV2EncoderImpl::LoadKeras(const io::KerasLayersModel& model) { backbone_->LoadKeras(model); }

std::vector<torch::Tensor> MobileNetV2EncoderImpl::Stages(const torch::Tensor& x) {
  AVATAR_CHECK_INPUT(x.dim() == 4 && x.size(2) % 32 == 0 && x.size(3) % 32 == 0)
      << "MobileNetV2 encoder input must be [B,C,H,W] with H and W multiples of 32, got " << x.sizes();
  return backbone_->Features(x, StageTaps());
}

torch::Tensor MobileNetV2EncoderImpl::forward(const torch::Tensor& x) {
  const auto stages = Stages(x);
  const int64_t h = stages[0].size(2), w = stages[0].size(3);
  std::vector<torch::Tensor> maps;
  for (size_t s = stages.size(); s-- > 0;) {
    torch::Tensor y = head_linears_[s]->forward(stages[s]);
    if (s > 0) y = torch::upsample_bilinear2d(y, {h, w}, /*align_corners=*/false);
    maps.push_back(y);
  }
  return fuse_->forward(torch::cat(maps, 1));  // [B,D,H/4,W/4]
}

double MobileNetV2Impl::Flops(int64_t h, int64_t w) const {
  const auto conv = [](const ConvBn& c, int64_t* ch, int64_t* cw) {
    const auto& o = c.conv->options;
    *ch /= c.stride;
    *cw /= c.stride;
    return ConvFlops(o.in_channels(), o.out_channels(), o.kernel_size()->at(0), *ch, *cw, o.groups());
  };
  double flops = conv(stem_, &h, &w);
  for (const Block& b : blocks_) {
    if (b.expand_conv.conv) flops += conv(b.expand_conv, &h, &w);
    flops += conv(b.depthwise, &h, &w);
    flops += conv(b.project, &h, &w);
  }
  return flops;
}

std::vector<FlopEntry> MobileNetV2EncoderImpl::Flops(int64_t size) const {
  double head = 0;
  const int64_t g = size / 4;
  for (size_t s = 0; s < StageTaps().size(); ++s) {
    const int64_t side = size / backbone_->TapStride(StageTaps()[s]);
    head += ConvFlops(backbone_->TapChannels(StageTaps()[s]), decoder_dim_, 1, side, side);
  }
  head += ConvFlops(4 * decoder_dim_, decoder_dim_, 1, g, g);
  return {{"backbone", backbone_->Flops(size, size)}, {"head", head}};
}

std::filesystem::path NsfwjsMobileNetV2Path(const std::string& data_dir) {
  return DataPaths::Resolve(data_dir).Path("models/nsfwjs/model.min.js");
}

MobileNetV2 LoadNsfwjsMobileNetV2(const std::string& data_dir, const MobileNetV2Options& options) {
  MobileNetV2 net(options);
  net->LoadKeras(io::LoadKerasLayersModel(NsfwjsMobileNetV2Path(data_dir)));
  net->Freeze();
  net->eval();
  return net;
}

}  // namespace avatar
