#include "app/cmd_inspect.h"

#include <cstdio>
#include <iostream>

#include "core/tools/network_summary.h"
#include "core/pipeline/quality.h"
#include "core/util/error.h"

namespace avatar::app {

namespace {

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
  NetworkSummaryOptions network;
  network.config = config;
  network.Validate();
  common.Validate();
}

int RunInspectImpl(const InspectOptions& options, RunContext& ctx) {
  options.Validate();
  NetworkSummaryOptions network;
  network.config = options.config;
  const NetworkSummary n = DescribeNetwork(network, ctx);

  std::cout << "GOHA network, config '" << n.config_name << "' (batch 1)\n" << n.config_json << "\n\n";
  std::cout << "| module | parameters | input | output |\n|---|---|---|---|\n";
  for (const NetworkModule& m : n.modules) {
    std::cout << "| " << m.name << " | "
              << (m.parameters > 0 ? Millions(static_cast<double>(m.parameters)) : std::string("-")) << " | "
              << m.input << " | " << m.output << " |\n";
  }
  std::cout << "\nTotal generator parameters: " << Millions(static_cast<double>(n.generator_parameters))
            << " (discriminator " << Millions(static_cast<double>(n.discriminator_parameters)) << ")\n\n";

  std::cout << "| stage | GFLOPs |\n|---|---|\n";
  for (const NetworkStage& e : n.stages) std::cout << "| " << e.name << " | " << Giga(e.flops) << " |\n";
  std::cout << "| dual discriminator | " << Giga(n.discriminator_flops) << " |\n";
  std::cout << "\nReconstruct (E_c, depth render, E_p, upsamplers): " << Giga(n.reconstruct_flops)
            << " GFLOPs; new expression (E_e): " << Giga(n.expression_flops)
            << " GFLOPs; frame (render + SR): " << Giga(n.frame_flops) << " GFLOPs; all: " << Giga(n.total_flops)
            << " GFLOPs.\n"
            << "FLOPs are analytic (multiply-add = 2): convs 2*Cin/groups*k^2*Cout*Hout*Wout, linear 2*in*out per "
               "token, attention 4*N*Nr*C; renders count the decoder MLP, "
            << n.decoder_flops_per_point << " FLOPs per sample x " << n.samples_per_ray
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
