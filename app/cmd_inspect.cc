#include "app/cmd_inspect.h"

#include <cstdio>
#include <iostream>
#include <sstream>

#include "core/model/goha_model.h"
#include "core/pipeline/quality.h"
#include "core/util/error.h"

namespace avatar::app {

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

std::string Millions(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.3f M", v / 1e6);
  return buf;
}

std::string Giga(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.2f", v / 1e9);
  return buf;
}

}  // namespace

void InspectOptions::Validate() const {
  ModelConfig::FromName(config);
  common.Validate();
}

int RunInspectImpl(const InspectOptions& options, RunContext& ctx) {
  options.Validate();
  const ModelConfig c = ModelConfig::FromName(options.config);
  ctx.ThrowIfCancelled();
  GohaModel model(c);
  DualDiscriminator disc(c);
  const int64_t s = c.image_size, g = c.feature_size(), p = c.plane_size(), ch = c.plane_channels;
  const int64_t d = c.decoder_dim, r = c.render_size, samples = c.num_coarse + c.num_importance;
  int64_t upsampler_params = 0;
  for (const auto& u : model->upsamplers) upsampler_params += CountParameters(*u);

  std::cout << "GOHA network, config '" << c.name << "' (batch 1)\n" << ModelConfigToJson(c) << "\n\n";
  std::cout << "| module | parameters | input | output |\n|---|---|---|---|\n";
  const auto row = [](const std::string& m, int64_t params, const std::string& in, const std::string& out) {
    std::cout << "| " << m << " | " << (params > 0 ? Millions(static_cast<double>(params)) : std::string("-")) << " | "
              << in << " | " << out << " |\n";
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
  row("E_e: " + backbone + " + decode head", CountParameters(*model->expression_encoder), "I_exp " + Shape({1, 3, s, s}),
      "F_e " + Shape({1, d, g, g}));
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
  std::cout << "\nTotal generator parameters: " << Millions(static_cast<double>(CountParameters(*model)))
            << " (discriminator " << Millions(static_cast<double>(CountParameters(*disc))) << ")\n\n";

  std::cout << "| stage | GFLOPs |\n|---|---|\n";
  double total = 0, reconstruct = 0, expression = 0, frame = 0;
  for (const auto& e : model->Flops()) {
    std::cout << "| " << e.module << " | " << Giga(e.flops) << " |\n";
    total += e.flops;
    if (e.module.rfind("E_c", 0) == 0 || e.module.rfind("E_p", 0) == 0 || e.module.rfind("appearance", 0) == 0) {
      reconstruct += e.flops;
    } else if (e.module.rfind("E_e", 0) == 0) {
      expression += e.flops;
    } else {
      frame += e.flops;
    }
  }
  std::cout << "| dual discriminator | " << Giga(disc->Flops()) << " |\n";
  std::cout << "\nReconstruct (E_c, depth render, E_p, upsamplers): " << Giga(reconstruct)
            << " GFLOPs; new expression (E_e): " << Giga(expression) << " GFLOPs; frame (render + SR): " << Giga(frame)
            << " GFLOPs; all: " << Giga(total) << " GFLOPs.\n"
            << "FLOPs are analytic (multiply-add = 2): convs 2*Cin/groups*k^2*Cout*Hout*Wout, linear 2*in*out per "
               "token, attention 4*N*Nr*C; renders count the decoder MLP, "
            << static_cast<int64_t>(model->decoder->FlopsPerPoint()) << " FLOPs per sample x " << samples
            << " samples per ray; norms, activations, "
               "plane lookups and the nearest-neighbour search are not counted.\n";
  SessionOptions session_options;
  session_options.data_dir = options.common.data_dir;
  std::cout << "\n" << QualityLadderHelp(session_options);
  return kExitOk;
}

int RunInspect(const std::vector<std::string>& args) {
  return GuardedRun("inspect", [&] {
    InspectOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio inspect [--config paper|lite|tiny]",
                      "Lists the GOHA network's modules with parameter counts, tensor shapes and analytic FLOPs,\n"
                      "then the quality ladder with this machine's cached time estimates.",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.empty()) << "inspect takes no positional arguments";
    return RunInspectImpl(options, ProcessContext());
  });
}

AVATAR_REGISTER_COMMAND("inspect", "list the network's modules, shapes, parameters and FLOPs", RunInspect);

}  // namespace avatar::app
