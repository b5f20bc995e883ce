#include "core/train/sample.h"

#include "core/util/error.h"

namespace avatar::train {

namespace {
torch::Tensor Stack(const std::vector<TrainSample>& samples, torch::Tensor TrainSample::*member, const char* name) {
  std::vector<torch::Tensor> parts;
  parts.reserve(samples.size());
  for (const auto& s : samples) {
    const torch::Tensor& t = s.*member;
    if (!t.defined()) throw InvalidInput(std::string("training sample without ") + name);
    if (!parts.empty() && t.sizes() != parts.front().sizes())
      throw InvalidInput(std::string("training samples of different shapes in ") + name);
    parts.push_back(t);
  }
  return torch::stack(parts);
}
}  // namespace

TrainBatch Collate(const std::vector<TrainSample>& samples) {
  if (samples.empty()) throw InvalidInput("cannot collate an empty list of training samples");
  TrainBatch b;
  b.source = Stack(samples, &TrainSample::source, "source");
  b.source_matte = Stack(samples, &TrainSample::source_matte, "source_matte");
  b.source_eye_mouth = Stack(samples, &TrainSample::source_eye_mouth, "source_eye_mouth");
  b.source_label = Stack(samples, &TrainSample::source_label, "source_label");
  b.target = Stack(samples, &TrainSample::target, "target");
  b.target_matte = Stack(samples, &TrainSample::target_matte, "target_matte");
  b.target_label = Stack(samples, &TrainSample::target_label, "target_label");
  b.expression_image = Stack(samples, &TrainSample::expression_image, "expression_image");
  b.neutral_image = Stack(samples, &TrainSample::neutral_image, "neutral_image");
  b.neutral_mask = Stack(samples, &TrainSample::neutral_mask, "neutral_mask");
  b.target_expression = Stack(samples, &TrainSample::target_expression, "target_expression");
  std::vector<int64_t> kinds, ids;
  for (const auto& s : samples) {
    kinds.push_back(static_cast<int64_t>(s.kind));
    ids.push_back(s.identity);
  }
  b.kind = torch::tensor(kinds, torch::kInt64);
  b.identity = torch::tensor(ids, torch::kInt64);
  return b;
}

TrainBatch TrainBatch::To(const torch::Device& device) const {
  auto f = [&](const torch::Tensor& t) { return t.defined() ? t.to(device, torch::kFloat32) : t; };
  TrainBatch b;
  b.source = f(source);
  b.source_matte = f(source_matte);
  b.source_eye_mouth = f(source_eye_mouth);
  b.source_label = f(source_label);
  b.target = f(target);
  b.target_matte = f(target_matte);
  b.target_label = f(target_label);
  b.expression_image = f(expression_image);
  b.neutral_image = f(neutral_image);
  b.neutral_mask = f(neutral_mask);
  b.target_expression = f(target_expression);
  b.kind = kind.defined() ? kind.to(device) : kind;
  b.identity = identity.defined() ? identity.to(device) : identity;
  return b;
}

}  // namespace avatar::train
