#pragma once
// The GOHA network described without running it, for `avatar-studio inspect`: its modules with
// parameter counts and tensor shapes at batch 1, and the analytic FLOPs of every stage (formulas
// in core/model/segformer.h), summed into reconstruct / new expression / frame.

#include <cstdint>
#include <string>
#include <vector>

#include "core/util/run_context.h"

namespace avatar {

struct NetworkSummaryOptions {
  // Network size: a config name (paper, lite, cpu, tiny).
  std::string config = "paper";

  template <typename V>
  void Visit(V&& v) {
    v("config", config, "Network size: paper, lite or tiny");
  }
  // Throws InvalidOptions for an unknown config.
  void Validate() const;
};

// One module of the network.
struct NetworkModule {
  std::string name;
  int64_t parameters = 0;  // 0: a step without parameters (a render, the rasterization)
  std::string input, output;  // shapes, e.g. "I_s [1,3,512,512]"
};

// One stage of the FLOP table.
struct NetworkStage {
  std::string name;
  double flops = 0.0;
};

struct NetworkSummary {
  std::string config_name;
  std::string config_json;                 // ModelConfigToJson of the config
  std::vector<NetworkModule> modules;      // generator modules, then the dual discriminator
  int64_t generator_parameters = 0;
  int64_t discriminator_parameters = 0;
  std::vector<NetworkStage> stages;        // the generator's stages in order
  double discriminator_flops = 0.0;
  // Sums of `stages`: E_c + E_p + appearance steps, E_e, everything else (render + SR), all.
  double reconstruct_flops = 0.0, expression_flops = 0.0, frame_flops = 0.0, total_flops = 0.0;
  int64_t decoder_flops_per_point = 0;     // tri-plane decoder MLP
  int64_t samples_per_ray = 0;             // coarse + importance
};

// Builds the network of the config (random weights) and describes it. Throws InvalidOptions,
// Cancelled.
NetworkSummary DescribeNetwork(const NetworkSummaryOptions& options, RunContext& ctx);

}  // namespace avatar
