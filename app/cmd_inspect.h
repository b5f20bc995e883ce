#pragma once
// `avatar-studio inspect --config paper|lite|tiny`: the network's modules with parameter
// counts, tensor shapes and analytic FLOPs per stage (formulas in core/model/segformer.h).

#include <string>

#include "app/commands.h"

namespace avatar::app {

struct InspectOptions {
  // Network size to describe.
  std::string config = "paper";
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("config", config, "Network size: paper, lite or tiny");
    common.Visit(v);
  }
  void Validate() const;
};

int RunInspect(const std::vector<std::string>& args);
// Prints the tables; throws avatar::Error; returns kExitOk.
int RunInspectImpl(const InspectOptions& options, RunContext& ctx);

}  // namespace avatar::app
