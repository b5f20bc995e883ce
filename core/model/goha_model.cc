#include "core/model/goha_model.h"

#include <cmath>
#include <set>
#include <sstream>

#include "core/model/mobilenet_v2.h"
#include "core/model/rasterize.h"
#include "core/model/segformer.h"
#include "core/render/rays.h"
#include "core/util/error.h"
#include "core/util/version.h"

namespace avatar {

namespace F = torch::nn::functional;

namespace {

torch::Tensor LRelu(const torch::Tensor& x) { return F::leaky_relu(x, F::LeakyReLUFuncOptions().negative_slope(0.2)); }

torch::nn::Conv2d Conv(int64_t in, int64_t out, int64_t k) {
  return torch::nn::Conv2d(torch::nn::Conv2dOptions(in, out, k).padding(k / 2));
}

torch::nn::ConvTranspose2d ConvUp(int64_t in, int64_t out) {
  return torch::nn::ConvTranspose2d(torch::nn::ConvTranspose2dOptions(in, out, 4).stride(2).padding(1));
}

}  // namespace

void ModelCounters::Reset() {
  canonical_encoder = 0;
  appearance_encoder = 0;
  expression_encoder = 0;
  rasterizations = 0;
  renders = 0;
  super_resolutions = 0;
}

Embed2PlaneImpl::Embed2PlaneImpl(int64_t in, int64_t width, int64_t mid, int64_t plane_channels)
    : in_(in), width_(width), mid_(mid), channels_(plane_channels) {
  conv1_ = register_module("conv1", Conv(in, width, 3));
  conv2_ = register_module("conv2", Conv(width, mid, 3));
  up_ = register_module("up", ConvUp(mid, mid));
  conv4_ = register_module("conv4", Conv(mid, mid, 3));
  conv5_ = register_module("conv5", Conv(mid, 3 * plane_channels, 3));
}

torch::Tensor Embed2PlaneImpl::forward(const torch::Tensor& x) {
  torch::Tensor y = LRelu(conv1_->forward(x));
  y = LRelu(conv2_->forward(y));
  y = LRelu(up_->forward(y));
  y = LRelu(conv4_->forward(y));
  y = conv5_->forward(y);                                          // [B,3C,2h,2w]
  return y.view({y.size(0), 3, channels_, y.size(2), y.size(3)});  // [B,3,C,2h,2w]
}

double Embed2PlaneImpl::Flops(int64_t h, int64_t w) const {
  // A stride-2 transposed conv costs in * out * k^2 MACs per input pixel.
  return ConvFlops(in_, width_, 3, h, w) + ConvFlops(width_, mid_, 3, h, w) + ConvFlops(mid_, mid_, 4, h, w) +
         ConvFlops(mid_, mid_, 3, 2 * h, 2 * w) + ConvFlops(mid_, 3 * channels_, 3, 2 * h, 2 * w);
}

PlaneUpsamplerImpl::PlaneUpsamplerImpl(int64_t in, int64_t width, int64_t out) : in_(in), width_(width), out_(out) {
  shortcut_ = register_module("shortcut", Conv(in, out, 1));
  up_ = register_module("up", ConvUp(in, width));
  conv_ = register_module("conv", Conv(width, out, 3));
}

torch::Tensor PlaneUpsamplerImpl::forward(const torch::Tensor& x) {
  const torch::Tensor base = shortcut_->forward(ResizeBilinear(x, 2 * x.size(2), 2 * x.size(3)));
  return base + conv_->forward(LRelu(up_->forward(x)));  // [B,out,2G,2G]
}

double PlaneUpsamplerImpl::Flops(int64_t h, int64_t w) const {
  return ConvFlops(in_, out_, 1, 2 * h, 2 * w) + ConvFlops(in_, width_, 4, h, w) +
         ConvFlops(width_, out_, 3, 2 * h, 2 * w);
}

namespace {

// The encoder of config.encoder for `in_channels` input channels; mobilenet_v2 backbones get
// `pretrained`'s weights when it is given.
ImageEncoder MakeEncoder(const ModelConfig& c, int64_t in_channels, const io::KerasLayersModel* pretrained) {
  if (c.encoder == "mobilenet_v2") {
    MobileNetV2Encoder enc(in_channels, c.decoder_dim);
    if (pretrained != nullptr) enc->LoadKeras(*pretrained);
    return ImageEncoder(std::shared_ptr<ImageEncoderImpl>(enc.ptr()));
  }
  return ImageEncoder(std::shared_ptr<ImageEncoderImpl>(SegFormerEncoder(c, in_channels).ptr()));
}

}  // namespace

GohaModelImpl::GohaModelImpl(const ModelConfig& config, const GohaModelOptions& options) : config_(config) {
  config_.Validate();
  const ModelConfig& c = config_;
  std::unique_ptr<io::KerasLayersModel> keras;
  if (c.encoder == "mobilenet_v2" && options.pretrained) {
    keras = std::make_unique<io::KerasLayersModel>(io::LoadKerasLayersModel(NsfwjsMobileNetV2Path(options.data_dir)));
  }
  canonical_encoder = register_module("canonical_encoder", MakeEncoder(c, 3, keras.get()));
  canonical_head =
      register_module("canonical_head", Embed2Plane(c.decoder_dim, c.head_width, c.head_mid_width, c.plane_channels));
  appearance_encoder = register_module("appearance_encoder", MakeEncoder(c, 6, keras.get()));
  for (int p = 0; p < 3; ++p) {
    upsamplers.push_back(register_module("appearance_upsampler" + std::to_string(p),
                                         PlaneUpsampler(c.decoder_dim, c.upsampler_width, c.plane_channels)));
  }
  expression_encoder = register_module("expression_encoder", MakeEncoder(c, 3, keras.get()));
  expression_head =
      register_module("expression_head", Embed2Plane(c.decoder_dim, c.head_width, c.head_mid_width, c.plane_channels));
  decoder = register_module("decoder", TriplaneDecoder(c.plane_channels, c.decoder_hidden, c.plane_channels));
  super_resolution = register_module("super_resolution", SuperResolution(c));
  if (c.expression_bases()) {
    // Zero bases: a network initialised from encoder weights starts as R(T_c + T_p).
    const int64_t k = c.expression_coefficients, p = c.plane_size();
    expression_bases = register_parameter("expression_bases", torch::zeros({k, 3, c.plane_channels, p, p}));
    expression_std = register_buffer("expression_std", torch::ones({k}));
  }
}

torch::Tensor GohaModelImpl::Normalise(const torch::Tensor& rgb) const {
  if (config_.encoder == "mobilenet_v2") return rgb;
  const auto opts = rgb.options();
  const torch::Tensor mean = torch::tensor({0.485, 0.456, 0.406}, opts).view({1, 3, 1, 1});
  const torch::Tensor std = torch::tensor({0.229, 0.224, 0.225}, opts).view({1, 3, 1, 1});
  return ((rgb + 1.0) * 0.5 - mean) / std;
}

namespace {

void CheckImage(const torch::Tensor& image, int64_t size, const char* what) {
  AVATAR_CHECK_INPUT(image.dim() == 4 && image.size(1) == 3 && image.size(2) == size && image.size(3) == size)
      << what << " must be [B,3," << size << "," << size << "], got " << image.sizes();
}

}  // namespace

torch::Tensor GohaModelImpl::CanonicalPlanes(const torch::Tensor& image) {
  CheckImage(image, config_.image_size, "source image");
  ++counters_.canonical_encoder;
  return canonical_head->forward(canonical_encoder->forward(Normalise(image)));
}

torch::Tensor GohaModelImpl::ExpressionPlanes(const torch::Tensor& expression_image) {
  AVATAR_CHECK_INPUT(!config_.expression_bases())
      << "model config '" << config_.name
      << "' has the linear expression branch (expression_model bases): its expression planes come from "
         "morphable expression coefficients (ExpressionPlanesFromCoefficients), not from I_exp";
  CheckImage(expression_image, config_.image_size, "expression image I_exp");
  ++counters_.expression_encoder;
  return expression_head->forward(expression_encoder->forward(Normalise(expression_image)));
}

torch::Tensor MixExpressionBases(const torch::Tensor& weights, const torch::Tensor& bases) {
  AVATAR_CHECK_INPUT(weights.dim() == 2 && bases.dim() >= 1 && weights.size(1) == bases.size(0))
      << "expression bases: weights must be [B,K] for " << bases.size(0) << " bases, got " << weights.sizes();
  std::vector<int64_t> shape = bases.sizes().vec();
  shape[0] = weights.size(0);
  return torch::matmul(weights, bases.reshape({bases.size(0), -1})).view(shape);
}

torch::Tensor GohaModelImpl::ExpressionPlanesFromCoefficients(const torch::Tensor& coefficients) {
  AVATAR_CHECK_INPUT(config_.expression_bases())
      << "model config '" << config_.name
      << "' has the expression encoder E_e (expression_model encoder): it takes I_exp, not coefficients";
  const int64_t k = config_.expression_coefficients;
  AVATAR_CHECK_INPUT(coefficients.defined() && coefficients.dim() == 2 && coefficients.size(1) == k)
      << "expression coefficients must be [B," << k << "] (the morphable model's expression components), got "
      << (coefficients.defined() ? coefficients.sizes() : torch::IntArrayRef{});
  ++counters_.expression_encoder;
  const torch::Tensor w = coefficients.to(expression_bases.options()) / expression_std;
  return MixExpressionBases(w, expression_bases);  // [B,3,C,P,P]
}

torch::Tensor GohaModelImpl::ExpressionPlanesFor(const torch::Tensor& expression_image,
                                                 const torch::Tensor& coefficients) {
  return config_.expression_bases() ? ExpressionPlanesFromCoefficients(coefficients)
                                    : ExpressionPlanes(expression_image);
}

void GohaModelImpl::SetExpressionStd(const std::vector<float>& std_per_coefficient) {
  AVATAR_CHECK_INPUT(config_.expression_bases()) << "SetExpressionStd: the model has no expression bases";
  AVATAR_CHECK_INPUT(static_cast<int64_t>(std_per_coefficient.size()) == config_.expression_coefficients)
      << "SetExpressionStd: " << std_per_coefficient.size() << " values for " << config_.expression_coefficients
      << " expression coefficients (the morphable model and the config disagree)";
  for (float v : std_per_coefficient)
    AVATAR_CHECK_INPUT(std::isfinite(v) && v > 0) << "SetExpressionStd: every std must be finite and > 0, got " << v;
  torch::NoGradGuard no_grad;
  expression_std.copy_(torch::tensor(std_per_coefficient, torch::kFloat32).to(expression_std.options()));
}

render::RenderOptions GohaModelImpl::RenderOptionsFor(int resolution, bool deterministic) const {
  render::RenderOptions opts;
  opts.resolution = resolution > 0 ? resolution : config_.render_size;
  opts.num_coarse = config_.num_coarse;
  opts.num_importance = config_.num_importance;
  opts.deterministic = deterministic;
  return opts;
}

render::RenderOutput GohaModelImpl::Render(const torch::Tensor& planes, const render::Cameras& cameras, int resolution,
                                           bool deterministic, render::RenderProfile* profile) {
  return RenderWith(planes, cameras, RenderOptionsFor(resolution, deterministic), profile);
}

render::RenderOutput GohaModelImpl::RenderWith(const torch::Tensor& planes, const render::Cameras& cameras,
                                               render::RenderOptions options, render::RenderProfile* profile) {
  ++counters_.renders;
  const render::PointDecoder decode = [this](const torch::Tensor& f) { return decoder->forward(f); };
  if (inference_skips) options.EnableInferenceSkips();
  if (options.skip_empty_space && options.occupancy == nullptr && !torch::GradMode::is_enabled()) {
    options.occupancy = OccupancyGridFor(planes);
  }
  return render::RenderTriplanes(planes, decode, cameras, options, c10::nullopt, profile);
}

render::DensityMlp DecoderDensityMlp(const TriplaneDecoder& decoder) {
  torch::NoGradGuard no_grad;
  const double in = static_cast<double>(decoder->fc1_weight.size(1));
  const double hidden = static_cast<double>(decoder->fc1_weight.size(0));
  // The same equalised-learning-rate gains as TriplaneDecoderImpl::forward.
  render::DensityMlp mlp;
  mlp.w1 = decoder->fc1_weight.detach() * (1.0 / std::sqrt(in));
  mlp.b1 = decoder->fc1_bias.detach().clone();
  mlp.w2 = decoder->fc2_weight.detach()[0] * (1.0 / std::sqrt(hidden));
  mlp.b2 = decoder->fc2_bias.detach()[0].item<double>();
  return mlp;
}

std::shared_ptr<const render::OccupancyGrid> GohaModelImpl::OccupancyGridFor(
    const torch::Tensor& planes, const render::OccupancyGridOptions& options) const {
  return render::BuildOccupancyGrid(planes.detach(), DecoderDensityMlp(decoder), RenderOptionsFor().box_warp, options);
}

AppearanceOutput GohaModelImpl::AppearancePlanes(const torch::Tensor& source, const torch::Tensor& eye_mouth,
                                                 const torch::Tensor& matte, const torch::Tensor& canonical_planes,
                                                 const render::Cameras& cameras) {
  const int64_t s = config_.image_size, g = config_.feature_size();
  CheckImage(source, s, "source image");
  const int64_t b = source.size(0);
  AVATAR_CHECK_INPUT(eye_mouth.dim() == 4 && eye_mouth.size(0) == b && eye_mouth.size(1) == 1 &&
                     eye_mouth.size(2) == s && eye_mouth.size(3) == s)
      << "eye/mouth mask must be [B,1," << s << "," << s << "], got " << eye_mouth.sizes();
  AVATAR_CHECK_INPUT(matte.sizes() == eye_mouth.sizes())
      << "matte must be [B,1," << s << "," << s << "], got " << matte.sizes();
  AVATAR_CHECK_INPUT(cameras.batch() == b) << "need one source camera per image";
  AppearanceOutput out;
  if (!config_.appearance_branch) {
    // The w/o-appearance ablation: T_p = 0, nothing runs.
    out.planes = torch::zeros_like(canonical_planes).detach();
    return out;
  }
  {
    torch::NoGradGuard no_grad;
    const render::RenderOutput canonical = Render(canonical_planes.detach(), cameras, static_cast<int>(g));
    out.canonical_rgb = canonical.rgb.contiguous();  // [B,3,G,G]
    out.depth = canonical.depth;                     // [B,1,G,G]
  }
  // Eyes, brows, lips and the inner mouth show the source's expression: replace them (dilated
  // 7x7, i.e. the keep-mask eroded) by the neutral canonical render before E_p sees the image.
  const torch::Tensor canonical_up = ResizeBilinear(out.canonical_rgb, s, s);  // [B,3,S,S]
  const torch::Tensor replace = F::max_pool2d(eye_mouth, F::MaxPool2dFuncOptions(7).stride(1).padding(3));
  const torch::Tensor masked_source = source * (1.0 - replace) + canonical_up * replace;
  ++counters_.appearance_encoder;
  const torch::Tensor features =
      appearance_encoder->forward(torch::cat({Normalise(masked_source), Normalise(canonical_up)}, 1));  // [B,D,G,G]

  ++counters_.rasterizations;
  const render::Rays rays = render::GenerateRays(cameras, g);  // [B,G*G,3]
  out.points = rays.origins + out.depth.reshape({b, g * g, 1}).to(rays.origins.dtype()) * rays.directions;
  // Lifting rule: a ray joins the point cloud when the person matte, averaged over the ray's
  // pixel footprint (area resize to G x G), is at least 0.5.
  const torch::Tensor matte_small =
      F::interpolate(matte, F::InterpolateFuncOptions().size(std::vector<int64_t>{g, g}).mode(torch::kArea));
  out.foreground = (matte_small.reshape({b, g * g}) >= 0.5);
  const torch::Tensor point_features = features.flatten(2).transpose(1, 2);  // [B,G*G,D]
  const torch::Tensor raster = RasterizePointFeatures(out.points, out.foreground, point_features, g,
                                                      RenderOptionsFor().box_warp);  // [B,3,D,G,G]
  std::vector<torch::Tensor> planes;
  for (int p = 0; p < 3; ++p) planes.push_back(upsamplers[p]->forward(raster.select(1, p)));  // [B,C,2G,2G]
  out.planes = torch::stack(planes, 1);                                                       // [B,3,C,P,P]
  return out;
}

torch::Tensor GohaModelImpl::SuperResolve(const torch::Tensor& rgb) {
  ++counters_.super_resolutions;
  return super_resolution->forward(rgb);
}

std::vector<FlopEntry> GohaModelImpl::Flops() const {
  std::vector<FlopEntry> out;
  const int64_t s = config_.image_size, g = config_.feature_size();
  const auto add_encoder = [&](const std::string& name, const ImageEncoder& enc) {
    for (const auto& e : enc->Flops(s)) out.push_back({name + "/" + e.module, e.flops});
  };
  const double per_sample = decoder->FlopsPerPoint() * (config_.num_coarse + config_.num_importance);
  add_encoder("E_c", canonical_encoder);
  out.push_back({"E_c/embed2plane", canonical_head->Flops(g, g)});
  if (config_.appearance_branch) {
    out.push_back({"appearance/depth_render", per_sample * g * g});
    add_encoder("E_p", appearance_encoder);
    double ups = 0;
    for (const auto& u : upsamplers) ups += u->Flops(g, g);
    out.push_back({"appearance/upsamplers", ups});
  }
  if (config_.expression_bases()) {
    const double p = static_cast<double>(config_.plane_size());
    out.push_back({"expression_bases", 2.0 * config_.expression_coefficients * 3 * config_.plane_channels * p * p});
  } else {
    add_encoder("E_e", expression_encoder);
    out.push_back({"E_e/embed2plane", expression_head->Flops(g, g)});
  }
  out.push_back({"render", per_sample * config_.render_size * config_.render_size});
  for (const auto& e : super_resolution->Flops()) out.push_back({"SR/" + e.module, e.flops});
  return out;
}

int64_t CountParameters(const torch::nn::Module& module) {
  int64_t n = 0;
  for (const auto& p : module.parameters()) n += p.numel();
  return n;
}

void SaveModelCheckpoint(const std::filesystem::path& path, GohaModel& model, const CheckpointInfo& info,
                         bool half_precision) {
  TensorArchive archive;
  archive.kind = "goha-model";
  archive.meta = {{"config", nlohmann::json::parse(ModelConfigToJson(model->config()))},
                  {"step", info.step},
                  {"data_provenance", info.data_provenance},
                  {"created_by", info.created_by.empty() ? std::string("avatar-studio ") + kVersion : info.created_by},
                  {"sr_trained", info.sr_trained}};
  // Shipping weights: floating tensors rounded to float16 (half the bytes); loading widens them.
  const auto stored = [&](const torch::Tensor& t) {
    return half_precision && t.is_floating_point() ? t.detach().to(torch::kCPU, torch::kFloat16) : t;
  };
  for (const auto& item : model->named_parameters(true)) archive.tensors.emplace_back(item.key(), stored(item.value()));
  for (const auto& item : model->named_buffers(true)) archive.tensors.emplace_back(item.key(), stored(item.value()));
  if (half_precision) archive.meta["precision"] = "float16";
  WriteTensorArchive(path, archive);
}

void LoadModelTensors(GohaModel& model, const TensorArchive& archive, const std::string& source) {
  std::set<std::string> used;
  torch::NoGradGuard no_grad;
  const auto load = [&](const std::string& name, torch::Tensor& dst) {
    const torch::Tensor& src = archive.Get(name, source);
    // A float16 file (shipping weights) loads into a floating model; nothing else changes type.
    const bool widened = src.scalar_type() == torch::kFloat16 && dst.is_floating_point();
    if (src.sizes() != dst.sizes() || (src.scalar_type() != dst.scalar_type() && !widened)) {
      std::ostringstream why;
      why << source << ": tensor '" << name << "' has shape " << src.sizes() << " " << src.scalar_type()
          << " but the model expects " << dst.sizes() << " " << dst.scalar_type();
      throw ModelLoad(why.str());
    }
    dst.copy_(src);
    used.insert(name);
  };
  for (auto& item : model->named_parameters(true)) load(item.key(), item.value());
  for (auto& item : model->named_buffers(true)) load(item.key(), item.value());
  for (const auto& [name, t] : archive.tensors) {
    if (used.count(name) == 0 && name.rfind("model.", 0) != 0 && name.rfind("avatar.", 0) != 0) {
      throw ModelLoad(source + ": unexpected tensor '" + name + "' (the file belongs to a different model version)");
    }
  }
}

LoadedModel LoadModelCheckpoint(const std::filesystem::path& path, std::string* fingerprint) {
  const TensorArchive archive = ReadTensorArchive(path, "goha-model", fingerprint);
  LoadedModel loaded;
  ModelConfig config;
  try {
    config = ModelConfigFromJson(archive.meta.at("config").dump());
    loaded.info.step = archive.meta.at("step").get<int64_t>();
    loaded.info.data_provenance = archive.meta.at("data_provenance").get<std::string>();
    loaded.info.created_by = archive.meta.value("created_by", std::string());
    loaded.info.sr_trained = archive.meta.value("sr_trained", false);
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(path.string() + ": checkpoint metadata is incomplete: " + e.what());
  } catch (const InvalidOptions& e) {
    throw ModelLoad(path.string() + ": checkpoint holds an invalid model config: " + e.what());
  }
  GohaModelOptions build;
  build.pretrained = false;  // every weight comes from the file
  loaded.model = GohaModel(config, build);
  LoadModelTensors(loaded.model, archive, path.string());
  loaded.model->eval();
  return loaded;
}

}  // namespace avatar
