#pragma once
// A Keras functional model of plain image layers, run in LibTorch: the graph of a TF.js
// layers-model file (core/io/keras_layers.h) executed node by node in NCHW. Used for the
// ESRGAN-family upscalers of @upscalerjs (RDN: convolutions, ReLU, concatenations, sums and a
// nearest-neighbour upsampling), measured as the 256 -> 512 step of exports (issue 33).
//
// Supported layers: InputLayer; Conv2D with stride 1, dilation 1, padding "same" (odd kernels)
// or "valid", activation linear/relu/sigmoid/tanh, with or without bias; Activation (the same
// four); Add; Concatenate on the channel axis; UpSampling2D (nearest). Anything else, or a model
// with more than one input or output, is refused when the net is built (ModelLoad naming the
// layer), never at run time.

#include <cstdint>
#include <string>
#include <vector>

#include <torch/torch.h>

#include "core/io/keras_layers.h"

namespace avatar {

class KerasNet {
 public:
  // Throws ModelLoad naming the model file and the layer for anything outside the list above,
  // a missing or misshapen weight, or a graph whose inputs are not defined before use.
  explicit KerasNet(const io::KerasLayersModel& model);

  // x [B,C,H,W] float in the model's own input range -> the output layer's tensor [B,C',H',W'].
  // Throws InvalidInput for another rank or channel count.
  torch::Tensor Forward(const torch::Tensor& x) const;

  // Channels the input layer takes (from its batch_input_shape; 0 when unspecified).
  int64_t InputChannels() const { return input_channels_; }
  // The product of the UpSampling2D factors along the output's path (1 when none).
  int64_t Scale() const { return scale_; }
  int64_t ParameterCount() const;
  // Multiply-adds of one forward pass at an input of h x w (convolutions only).
  double MultiplyAdds(int64_t h, int64_t w) const;

 private:
  struct Node {
    std::string name, op;          // op: input, conv, act, add, concat, up
    std::vector<int> inputs;       // indices into nodes_
    torch::Tensor weight, bias;    // conv: [O,I,kh,kw], [O] (bias may be undefined)
    int64_t padding = 0;           // conv: "same" = k / 2, "valid" = 0
    std::string activation = "linear";
    int64_t up = 1;                // up: factor (both axes)
  };
  std::vector<Node> nodes_;
  int64_t input_channels_ = 0;
  int64_t scale_ = 1;
};

}  // namespace avatar
