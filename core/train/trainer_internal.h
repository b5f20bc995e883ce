#pragma once
// The trainer's helpers that both stages' steps use, defined once (the unity build batches the two).

#include <cmath>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <torch/torch.h>

#include "core/train/trainer.h"

namespace avatar::train::detail {

// Global L2 norm of the gradients (float64), or NaN when one is not finite.
inline double GradNorm(const std::vector<torch::Tensor>& params, const torch::Device& device) {
  torch::Tensor sq = torch::zeros({}, torch::TensorOptions().dtype(torch::kFloat64).device(device));
  for (const auto& p : params)
    if (p.grad().defined()) sq += p.grad().to(torch::kFloat64).pow(2).sum();
  return std::sqrt(sq.item<double>());
}

// The sum of the weighted loss terms; each term's batch mean is logged into `logged`.
inline torch::Tensor SumTerms(const std::map<std::string, torch::Tensor>& terms,
                              std::map<std::string, double>& logged) {
  torch::Tensor total;
  for (const auto& [name, t] : terms) {
    total = total.defined() ? total + t : t;
    logged[name] = t.item<double>();
  }
  return total;
}

// Measures the gradient norm into `norm`; false (with `reason`) when it is not finite.
inline bool FiniteGradNorm(const std::vector<torch::Tensor>& params, const torch::Device& device, double& norm,
                           std::string& reason, const char* what) {
  norm = GradNorm(params, device);
  if (std::isfinite(norm)) return true;
  reason = what;
  return false;
}

inline void ClearGrads(std::vector<torch::Tensor>& params) {
  for (auto& p : params) p.mutable_grad() = torch::Tensor();
}

inline std::vector<std::string> KeysOf(const std::map<std::string, double>& m) {
  std::vector<std::string> keys;
  for (const auto& item : m) keys.push_back(item.first);
  return keys;
}

// Data parallelism: the gradients of `params` and the step's reported numbers (`scalars`, and
// the entries `keys` of each map; an entry a rank lacks counts as NaN) averaged over the ranks.
// Returns whether every rank's loss was finite; when only another rank's was not, says so in
// r.skip_reason.
using MapKeys = std::pair<std::map<std::string, double>*, std::vector<std::string>>;
inline bool ReduceOverRanks(GradientReducer& reducer, bool local_ok, const std::vector<double*>& scalars,
                            const std::vector<MapKeys>& maps, const std::vector<torch::Tensor>& params, StepResult& r) {
  std::vector<double> values;
  for (const double* v : scalars) values.push_back(*v);
  for (const auto& [map, keys] : maps)
    for (const auto& key : keys) {
      const auto it = map->find(key);
      values.push_back(it != map->end() ? it->second : std::nan(""));
    }
  const bool all_ok = reducer.ReduceGradients(params, local_ok, values);
  size_t i = 0;
  for (double* v : scalars) *v = values[i++];
  for (const auto& [map, keys] : maps)
    for (const auto& key : keys) (*map)[key] = values[i++];
  if (local_ok && !all_ok) r.skip_reason = "non-finite loss on another rank";
  return all_ok;
}

}  // namespace avatar::train::detail
