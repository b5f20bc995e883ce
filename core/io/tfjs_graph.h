#pragma once
// A runtime for TensorFlow.js "graph-model" files (model.json + weight shards) on LibTorch.
//
// The model's GraphDef is interpreted node by node; each TF op maps to a LibTorch call with
// TF's exact NHWC semantics (asymmetric SAME padding, HWIO / depthwise filter layouts,
// half-pixel bilinear resize). Activations are kept as logical NHWC tensors; convolutions view
// them as channels-last NCHW, so no copies are made around torch's conv kernels.
//
// Loading validates everything up front: JSON shape, every weight shard present with the
// exact byte size the manifest implies, every op supported, every input resolvable. Any
// problem is an avatar::ModelLoad naming the model file, the node and the op.

#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <torch/torch.h>

namespace avatar::io {

class TfjsGraph {
 public:
  // Loads `model_json` and the shards it names (relative to its folder). Throws ModelLoad.
  explicit TfjsGraph(const std::filesystem::path& model_json);
  ~TfjsGraph();
  TfjsGraph(TfjsGraph&&) noexcept;
  TfjsGraph& operator=(TfjsGraph&&) noexcept;

  // Runs the graph. `inputs` maps input names (signature keys such as "input_1", tensor
  // names such as "input:0", or node names) to float32 NHWC tensors; `outputs` lists the
  // wanted outputs by the same kinds of names. Returns one tensor per requested output.
  // Thread-safe (const, no shared mutable state). Throws InvalidInput for a wrong input
  // shape or unknown name, ModelLoad for a graph that turns out inconsistent while running.
  std::vector<torch::Tensor> Run(const std::map<std::string, torch::Tensor>& inputs,
                                 const std::vector<std::string>& outputs) const;

  // Convenience for single-input models: the first placeholder.
  std::vector<torch::Tensor> Run(const torch::Tensor& input, const std::vector<std::string>& outputs) const;

  // The model's file (for messages).
  const std::filesystem::path& Path() const;
  // Names of the placeholder nodes, in graph order.
  std::vector<std::string> InputNames() const;
  // Declared shape of a placeholder (-1 for unknown dimensions).
  std::vector<int64_t> InputShape(const std::string& name) const;
  // Signature output keys (may be empty when the model has no signature outputs).
  std::vector<std::string> SignatureOutputs() const;
  // Distinct ops the graph uses, sorted.
  std::vector<std::string> Ops() const;

  // Every op this runtime executes.
  static std::vector<std::string> SupportedOps();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace avatar::io
