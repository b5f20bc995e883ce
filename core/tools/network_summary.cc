#include "core/tools/network_summary.h"

#include <sstream>

#include "core/model/goha_model.h"

namespace avatar {
namespace {

std::string Shape(std::initializer_list<int64_t> dims) {
  std::ostringstream s;
  s << "[";
  bool first = true;
  for (int64_t d : dims) {
    s << (first ? "" : ",") << d;
    first = false;
  }
  return s.str() + "]";
}

}  // namespace

void NetworkSummaryOptions::Validate() const { ModelConfig::FromName(config); }

NetworkSummary DescribeNetwork(const NetworkSummaryOptions& options, RunContext& ctx) {
  options.Validate();
  const ModelConfig c = ModelConfig::FromName(options.config);
  ctx.ThrowIfCancelled();
  GohaModel model(c);
  DualDiscriminator disc(c);
  const int64_t s = c.image_size, g = c.feature_size(), p = c.plane_size(), ch = c.plane_channels;
  const int64_t d = c.decoder_dim, r = c.render_size;
  int64_t upsampler_params = 0;
  for (const auto& u : model->upsamplers) upsampler_params += CountParameters(*u);

  NetworkSummary out;
  out.config_name = c.name;
  out.config_json = ModelConfigToJson(c);
  const auto row = [&](const std::string& m, int64_t params, const std::string& in, const std::string& o) {
    out.modules.push_back({m, params, in, o});
  };
  const std::string backbone = c.encoder == "mobilenet_v2" ? "MobileNetV2 (nsfwjs)" : "SegFormer MiT";
  row("E_c: " + backbone + " + decode head (to 1x1 fuse)", CountParameters(*model->canonical_encoder),
      "I_s " + Shape({1, 3, s, s}), "F_c " + Shape({1, d, g, g}));
  row("E_c: Embed2Plane", CountParameters(*model->canonical_head), Shape({1, d, g, g}),
      "T_c " + Shape({1, 3, ch, p, p}));
  row("appearance: depth render of T_c at C_s", 0, "T_c",
      "D_s " + Shape({1, 1, g, g}) + ", I_c " + Shape({1, 3, g, g}));
  row("E_p: " + backbone + " (6-channel input) + decode head", CountParameters(*model->appearance_encoder),
      Shape({1, 6, s, s}), "F " + Shape({1, d, g, g}));
  row("appearance: lifting + rasterization (k-d tree)", 0, "P " + Shape({1, g * g, 3}) + ", F", Shape({1, 3, d, g, g}));
  row("appearance: 3 upsamplers (one per plane)", upsampler_params, Shape({1, d, g, g}) + " x3",
      "T_p " + Shape({1, 3, ch, p, p}));
  row("E_e: " + backbone + " + decode head", CountParameters(*model->expression_encoder),
      "I_exp " + Shape({1, 3, s, s}), "F_e " + Shape({1, d, g, g}));
  row("E_e: Embed2Plane", CountParameters(*model->expression_head), Shape({1, d, g, g}),
      "T_e " + Shape({1, 3, ch, p, p}));
  row("tri-plane decoder (per point)", CountParameters(*model->decoder), Shape({ch}), Shape({1 + ch}));
  row("volume render of T_c + T_p + T_e", 0, Shape({1, 3, ch, p, p}),
      Shape({1, 3, r, r}) + " (" + std::to_string(c.num_coarse) + "+" + std::to_string(c.num_importance) +
          " samples/ray)");
  row("super-resolution (GFPGAN-v1-clean style)", CountParameters(*model->super_resolution), Shape({1, 3, r, r}),
      Shape({1, 3, c.sr_size, c.sr_size}));
  row("dual discriminator (training stage 2)", CountParameters(*disc), Shape({1, 6, c.sr_size, c.sr_size}),
      Shape({1, 1}));
  out.generator_parameters = CountParameters(*model);
  out.discriminator_parameters = CountParameters(*disc);

  for (const auto& e : model->Flops()) {
    out.stages.push_back({e.module, e.flops});
    out.total_flops += e.flops;
    if (e.module.rfind("E_c", 0) == 0 || e.module.rfind("E_p", 0) == 0 || e.module.rfind("appearance", 0) == 0) {
      out.reconstruct_flops += e.flops;
    } else if (e.module.rfind("E_e", 0) == 0) {
      out.expression_flops += e.flops;
    } else {
      out.frame_flops += e.flops;
    }
  }
  out.discriminator_flops = disc->Flops();
  out.decoder_flops_per_point = static_cast<int64_t>(model->decoder->FlopsPerPoint());
  out.samples_per_ray = c.num_coarse + c.num_importance;
  return out;
}

}  // namespace avatar
