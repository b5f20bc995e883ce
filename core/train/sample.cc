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
  TrainBatch b = Map([&](const torch::Tensor& t) { return t.to(device, torch::kFloat32); });
  b.kind = kind.defined() ? kind.to(device) : kind;
  b.identity = identity.defined() ? identity.to(device) : identity;
  return b;
}

TrainBatch TrainBatch::Map(const std::function<torch::Tensor(const torch::Tensor&)>& f) const {
  auto g = [&](const torch::Tensor& t) { return t.defined() ? f(t) : t; };
  TrainBatch b;
  b.source = g(source);
  b.source_matte = g(source_matte);
  b.source_eye_mouth = g(source_eye_mouth);
  b.source_label = g(source_label);
  b.target = g(target);
  b.target_matte = g(target_matte);
  b.target_label = g(target_label);
  b.expression_image = g(expression_image);
  b.neutral_image = g(neutral_image);
  b.neutral_mask = g(neutral_mask);
  b.target_expression = g(target_expression);
  b.kind = g(kind);
  b.identity = g(identity);
  return b;
}

}  // namespace avatar::train
