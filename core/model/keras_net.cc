#include "core/model/keras_net.h"

#include <algorithm>
#include <map>

#include "core/util/error.h"

namespace avatar {
namespace {

namespace F = torch::nn::functional;

[[noreturn]] void Refuse(const io::KerasLayersModel& model, const io::KerasLayer& layer, const std::string& what) {
  throw ModelLoad("model " + model.path.string() + ", layer '" + layer.name + "' (" + layer.class_name + "): " + what);
}

std::string Activation(const io::KerasLayersModel& model, const io::KerasLayer& layer) {
  const std::string a = layer.config.value("activation", "linear");
  if (a != "linear" && a != "relu" && a != "sigmoid" && a != "tanh") Refuse(model, layer, "activation '" + a + "'");
  return a;
}

torch::Tensor Apply(const std::string& activation, torch::Tensor x) {
  if (activation == "relu") return torch::relu(x);
  if (activation == "sigmoid") return torch::sigmoid(x);
  if (activation == "tanh") return torch::tanh(x);
  return x;
}

// A [h, w] pair of a config field (Keras writes lists; a single number means both).
std::pair<int64_t, int64_t> Pair(const nlohmann::json& v) {
  if (v.is_array() && v.size() == 2) return {v[0].get<int64_t>(), v[1].get<int64_t>()};
  return {v.get<int64_t>(), v.get<int64_t>()};
}

}  // namespace

KerasNet::KerasNet(const io::KerasLayersModel& model) {
  std::map<std::string, int> index;
  for (const io::KerasLayer& layer : model.layers) {
    Node n;
    n.name = layer.name;
    for (const std::string& in : layer.inbound) {
      const auto it = index.find(in);
      if (it == index.end()) Refuse(model, layer, "its input '" + in + "' comes later in the graph or does not exist");
      n.inputs.push_back(it->second);
    }
    const std::string& kind = layer.class_name;
    try {
      if (kind == "InputLayer") {
        n.op = "input";
        if (!nodes_.empty() && std::any_of(nodes_.begin(), nodes_.end(), [](const Node& m) { return m.op == "input"; }))
          Refuse(model, layer, "more than one input");
        const nlohmann::json shape = layer.config.value("batch_input_shape", nlohmann::json());
        if (shape.is_array() && shape.size() == 4 && shape[3].is_number()) input_channels_ = shape[3].get<int64_t>();
      } else if (kind == "Conv2D") {
        n.op = "conv";
        if (Pair(layer.config.value("strides", nlohmann::json(1))) != std::make_pair<int64_t, int64_t>(1, 1))
          Refuse(model, layer, "strides other than 1");
        if (Pair(layer.config.value("dilation_rate", nlohmann::json(1))) != std::make_pair<int64_t, int64_t>(1, 1))
          Refuse(model, layer, "dilation other than 1");
        if (layer.config.value("data_format", "channels_last") != "channels_last")
          Refuse(model, layer, "data_format other than channels_last");
        const auto [kh, kw] = Pair(layer.config.at("kernel_size"));
        const std::string padding = layer.config.value("padding", "valid");
        if (padding == "same") {
          if (kh != kw || kh % 2 == 0) Refuse(model, layer, "'same' padding of an even or non-square kernel");
          n.padding = kh / 2;
        } else if (padding != "valid") {
          Refuse(model, layer, "padding '" + padding + "'");
        }
        n.activation = Activation(model, layer);
        // Keras HWIO -> LibTorch OIHW.
        const torch::Tensor& k = model.Weight(layer.name + "/kernel");
        if (k.dim() != 4 || k.size(0) != kh || k.size(1) != kw) Refuse(model, layer, "a kernel of the wrong shape");
        n.weight = k.permute({3, 2, 0, 1}).contiguous();
        if (layer.config.value("use_bias", true)) {
          n.bias = model.Weight(layer.name + "/bias").contiguous();
          if (n.bias.dim() != 1 || n.bias.size(0) != n.weight.size(0)) Refuse(model, layer, "a bias of the wrong shape");
        }
      } else if (kind == "Activation") {
        n.op = "act";
        n.activation = Activation(model, layer);
      } else if (kind == "Add") {
        n.op = "add";
      } else if (kind == "Concatenate") {
        n.op = "concat";
        const int axis = layer.config.value("axis", -1);
        if (axis != -1 && axis != 3) Refuse(model, layer, "concatenation along axis " + std::to_string(axis));
      } else if (kind == "UpSampling2D") {
        n.op = "up";
        if (layer.config.value("interpolation", "nearest") != "nearest") Refuse(model, layer, "interpolation other than nearest");
        const auto [sh, sw] = Pair(layer.config.value("size", nlohmann::json(2)));
        if (sh != sw || sh < 1) Refuse(model, layer, "unequal or bad factors");
        n.up = sh;
      } else {
        Refuse(model, layer, "this layer type is not supported");
      }
    } catch (const nlohmann::json::exception& e) {
      Refuse(model, layer, std::string("malformed config: ") + e.what());
    }
    const size_t want = n.op == "input" ? 0 : (n.op == "add" || n.op == "concat") ? 2 : 1;
    if (n.op == "add" || n.op == "concat" ? n.inputs.size() < want : n.inputs.size() != want)
      Refuse(model, layer, std::to_string(n.inputs.size()) + " inputs");
    index[n.name] = static_cast<int>(nodes_.size());
    nodes_.push_back(std::move(n));
  }
  if (nodes_.empty() || nodes_.front().op != "input") throw ModelLoad("model " + model.path.string() + ": no input layer first");
  // Every node but the last feeds another: a single output, the last layer.
  std::vector<int> consumers(nodes_.size(), 0);
  for (const Node& n : nodes_)
    for (int i : n.inputs) ++consumers[static_cast<size_t>(i)];
  for (size_t i = 0; i + 1 < nodes_.size(); ++i) {
    if (consumers[i] == 0) throw ModelLoad("model " + model.path.string() + ": layer '" + nodes_[i].name + "' is a second output");
  }
  for (int i = static_cast<int>(nodes_.size()) - 1; i > 0; i = nodes_[static_cast<size_t>(i)].inputs.front()) {
    if (nodes_[static_cast<size_t>(i)].op == "up") scale_ *= nodes_[static_cast<size_t>(i)].up;
  }
}

torch::Tensor KerasNet::Forward(const torch::Tensor& x) const {
  AVATAR_CHECK_INPUT(x.defined() && x.dim() == 4 && (input_channels_ == 0 || x.size(1) == input_channels_))
      << "the network takes [B," << input_channels_ << ",H,W], got " << (x.defined() ? x.sizes() : torch::IntArrayRef{});
  std::vector<torch::Tensor> values(nodes_.size());
  // Free a value once its last consumer ran (the upscalers' feature maps are large).
  std::vector<int> remaining(nodes_.size(), 0);
  for (const Node& n : nodes_)
    for (int i : n.inputs) ++remaining[static_cast<size_t>(i)];
  for (size_t k = 0; k < nodes_.size(); ++k) {
    const Node& n = nodes_[k];
    auto in = [&](size_t j) -> const torch::Tensor& { return values[static_cast<size_t>(n.inputs[j])]; };
    torch::Tensor y;
    if (n.op == "input") {
      y = x;
    } else if (n.op == "conv") {
      y = Apply(n.activation, F::conv2d(in(0), n.weight, F::Conv2dFuncOptions().bias(n.bias).padding(n.padding)));
    } else if (n.op == "act") {
      y = Apply(n.activation, in(0));
    } else if (n.op == "add") {
      y = in(0).clone();
      for (size_t j = 1; j < n.inputs.size(); ++j) y.add_(in(j));
    } else if (n.op == "concat") {
      std::vector<torch::Tensor> parts;
      for (size_t j = 0; j < n.inputs.size(); ++j) parts.push_back(in(j));
      y = torch::cat(parts, 1);
    } else {  // up
      y = in(0).repeat_interleave(n.up, 2).repeat_interleave(n.up, 3);
    }
    values[k] = std::move(y);
    for (int i : n.inputs) {
      if (--remaining[static_cast<size_t>(i)] == 0) values[static_cast<size_t>(i)] = torch::Tensor();
    }
  }
  return values.back();
}

int64_t KerasNet::ParameterCount() const {
  int64_t count = 0;
  for (const Node& n : nodes_) {
    if (n.weight.defined()) count += n.weight.numel();
    if (n.bias.defined()) count += n.bias.numel();
  }
  return count;
}

double KerasNet::MultiplyAdds(int64_t h, int64_t w) const {
  // Spatial size of every node (convolutions with 'valid' padding shrink it, upsampling grows it).
  std::vector<std::pair<int64_t, int64_t>> size(nodes_.size(), {h, w});
  double total = 0.0;
  for (size_t k = 0; k < nodes_.size(); ++k) {
    const Node& n = nodes_[k];
    if (n.op == "input") continue;
    auto s = size[static_cast<size_t>(n.inputs.front())];
    if (n.op == "up") {
      s = {s.first * n.up, s.second * n.up};
    } else if (n.op == "conv") {
      s = {s.first + 2 * n.padding - n.weight.size(2) + 1, s.second + 2 * n.padding - n.weight.size(3) + 1};
      total += static_cast<double>(s.first * s.second) * static_cast<double>(n.weight.numel());
    }
    size[k] = s;
  }
  return total;
}

}  // namespace avatar
