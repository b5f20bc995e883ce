#pragma once
// A dataset shard as core/pipeline/dataset_build writes it (torch::pickle_save of a dict of
// tensors), with random pixels, for tests and fuzz seeds that need a loadable split without a
// dataset build. Shared by tests/pipeline/eval_test.cc and tests/fuzz/dataset_fuzz.cc.

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <torch/serialize.h>
#include <torch/torch.h>

namespace avatar::testing {

// n frames of s x s pixels (uint8, drawn from the global generator in a fixed order), labels and
// k expression coefficients (uniform), `identity` [n] int64; then `pairs_and_kinds()` gives the
// pairs [P,2] and their kinds [P] (0 photo, 1 clip, 2 synthetic), drawn last.
inline std::string DatasetShardBytes(int64_t n, int64_t s, int64_t k, const torch::Tensor& identity,
                                     const std::function<std::pair<torch::Tensor, torch::Tensor>()>& pairs_and_kinds) {
  auto u8 = [&](int64_t c) { return torch::randint(0, 256, {n, c, s, s}, torch::kUInt8); };
  c10::Dict<std::string, torch::Tensor> d;
  d.insert("image", u8(3));
  d.insert("matte", u8(1));
  d.insert("eye_mouth", u8(1));
  d.insert("expression_image", u8(3));
  d.insert("neutral_image", u8(3));
  d.insert("neutral_mask", u8(1));
  d.insert("label", torch::rand({n, 25}));
  d.insert("expression", torch::rand({n, k}));
  d.insert("identity", identity);
  const auto [pairs, kinds] = pairs_and_kinds();
  d.insert("pairs", pairs);
  d.insert("pair_kind", kinds);
  const std::vector<char> bytes = torch::pickle_save(c10::IValue(d));
  return std::string(bytes.begin(), bytes.end());
}

}  // namespace avatar::testing
