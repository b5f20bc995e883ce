#pragma once
// Sizes of the GOHA network. One struct describes every module; it is stored in every
// checkpoint and avatar file so that a file is always loaded into the network it was made with.
//
// Named configs (the network sizes; --config NAME):
//   paper : every size as published (512 input, SegFormer MiT-b0, planes 3x32x256x256, render
//           128x128 with 48+48 samples, GFPGAN-v1-clean-style SR to 512 with channel multiplier 2).
//   lite  : same encoders at a 256 input (planes 3x32x128x128), render 64x64 with 24+24
//           samples and a narrower SR to 256: the render is the part an orbiting preview repeats,
//           and `bench render` measured ~0.1 s for this size on 2 cores (docs/PERFORMANCE.md).
//   tiny  : a few thousand parameters per module, for tests only.
// All three configs use the mit_b0 encoder; `encoder` = mobilenet_v2 swaps in the pretrained
// MobileNetV2 (see the field).
//
// Ablation variants (issue 14, the paper's Table 4; every named config has the full design):
//   appearance_branch false   : no appearance planes: T_p = 0, the output is R(T_c + T_e).
//   expression_model "bases"  : T_e = sum_k (beta_k / std_k) B_k with learned tri-plane bases
//                               B_k instead of E_e over I_exp (expression_coefficients = K).
// Files written before these fields existed read as the full design.

#include <string>
#include <vector>

namespace avatar {

struct ModelConfig {
  // Config name (paper, lite, tiny or custom); informative only.
  std::string name = "paper";
  // Side of the square encoder input (source image, canonical render, I_exp).
  int image_size = 512;
  // Backbone of the three encoders E_c, E_p, E_e: "mit_b0" (SegFormer MiT, sized by the
  // encoder_* fields below, random initialisation) or "mobilenet_v2" (Keras MobileNetV2 with
  // nsfwjs's pretrained weights and an all-MLP decode head to decoder_dim; the encoder_* fields
  // are then unused). A config stored without the field (files made before it existed) reads
  // as mit_b0.
  std::string encoder = "mit_b0";
  // Channels of the four SegFormer (MiT) stages.
  std::vector<int> encoder_widths = {32, 64, 160, 256};
  // Transformer blocks per stage.
  std::vector<int> encoder_depths = {2, 2, 2, 2};
  // Attention heads per stage.
  std::vector<int> encoder_heads = {1, 2, 5, 8};
  // Spatial-reduction ratio of the keys/values per stage.
  std::vector<int> encoder_sr_ratios = {8, 4, 2, 1};
  // Hidden width of the Mix-FFN as a multiple of the stage width.
  int encoder_mlp_ratio = 4;
  // Channels of the all-MLP decode head (and of the encoder feature map F).
  int decoder_dim = 256;
  // Embed2Plane: width of the first 3x3 conv.
  int head_width = 256;
  // Embed2Plane: width after the second conv (also the transposed conv and the fourth conv).
  int head_mid_width = 128;
  // Feature channels per plane (also the tri-plane decoder's input and output features).
  int plane_channels = 32;
  // Hidden width of the tri-plane decoder MLP.
  int decoder_hidden = 64;
  // Appearance upsampler: width of the transposed convolution.
  int upsampler_width = 128;
  // Rendered image side for the final (and training) render.
  int render_size = 128;
  // Stratified samples per ray.
  int num_coarse = 48;
  // Importance samples per ray.
  int num_importance = 48;
  // Super-resolution output side (a power of two >= 16).
  int sr_size = 512;
  // GFPGAN channel multiplier (channels at resolution r: min(sr_max_channels, 16384 * m / r)).
  int sr_channel_multiplier = 2;
  // Upper bound on the SR channels at any resolution.
  int sr_max_channels = 512;
  // Width of each style vector of the SR decoder.
  int sr_style_dim = 512;
  // Upper bound on the discriminator's channels.
  int disc_max_channels = 512;
  // Appearance branch (E_p, lifting, upsamplers). False = the w/o-appearance ablation: the
  // modules stay in the network (and its files) but never run and never train;
  // AppearancePlanes returns zero planes, so every renderer shows R(T_c + T_e).
  bool appearance_branch = true;
  // Expression branch: "encoder" (the paper's E_e + Embed2Plane over the morphable render
  // I_exp) or "bases" (the paper's "linear expression" ablation: T_e = sum_k (beta_k / std_k) B_k,
  // K = expression_coefficients learned tri-planes [3,C,P,P] mixed by the target's morphable
  // expression coefficients beta, each divided by its morphable-model std (a buffer of the
  // network); E_e and its head then stay in the network unused and untrained).
  std::string expression_model = "encoder";
  // Number of morphable expression coefficients K the bases take (expression_model "bases";
  // our morphable model has 26). Unused for "encoder".
  int expression_coefficients = 26;

  template <typename V>
  void Visit(V&& v) {
    v("name", name, "Config name");
    v("image_size", image_size, "Encoder input side");
    v("encoder", encoder, "Encoder backbone: mit_b0 or mobilenet_v2");
    v("encoder_widths", encoder_widths, "MiT stage widths");
    v("encoder_depths", encoder_depths, "MiT blocks per stage");
    v("encoder_heads", encoder_heads, "MiT heads per stage");
    v("encoder_sr_ratios", encoder_sr_ratios, "MiT spatial-reduction ratios");
    v("encoder_mlp_ratio", encoder_mlp_ratio, "Mix-FFN expansion");
    v("decoder_dim", decoder_dim, "Decode head channels");
    v("head_width", head_width, "Embed2Plane first conv width");
    v("head_mid_width", head_mid_width, "Embed2Plane middle width");
    v("plane_channels", plane_channels, "Channels per plane");
    v("decoder_hidden", decoder_hidden, "Tri-plane decoder hidden width");
    v("upsampler_width", upsampler_width, "Appearance upsampler width");
    v("render_size", render_size, "Rendered image side");
    v("num_coarse", num_coarse, "Stratified samples per ray");
    v("num_importance", num_importance, "Importance samples per ray");
    v("sr_size", sr_size, "Super-resolution output side");
    v("sr_channel_multiplier", sr_channel_multiplier, "GFPGAN channel multiplier");
    v("sr_max_channels", sr_max_channels, "SR channel cap");
    v("sr_style_dim", sr_style_dim, "SR style width");
    v("disc_max_channels", disc_max_channels, "Discriminator channel cap");
    v("appearance_branch", appearance_branch, "Appearance branch (false: the w/o-appearance ablation)");
    v("expression_model", expression_model, "Expression branch: encoder (E_e over I_exp) or bases (linear)");
    v("expression_coefficients", expression_coefficients, "Expression coefficients mixing the bases");
  }

  // Throws InvalidOptions for inconsistent sizes (4 stages, widths divisible by heads,
  // image_size divisible by 32, powers of two where needed, positive widths).
  void Validate() const;

  // Side of the encoder feature map F (= image_size / 4) and of the lifting depth render.
  int feature_size() const { return image_size / 4; }
  // Side of each plane (= 2 * feature_size: the head's transposed conv doubles it).
  int plane_size() const { return image_size / 2; }
  // SR channels at resolution r.
  int SrChannels(int resolution) const;
  // expression_model == "bases".
  bool expression_bases() const { return expression_model == "bases"; }

  static ModelConfig Paper();
  static ModelConfig Lite();
  // The CPU training default: pretrained MobileNetV2 encoders at a 128 input, planes
  // 3x32x64^2, 32^2 renders with 24+24 samples, a narrow SR to 128 (docs/DEVIATIONS.md).
  static ModelConfig Cpu();
  static ModelConfig Tiny();
  // "paper", "lite", "cpu" or "tiny"; throws InvalidOptions otherwise.
  static ModelConfig FromName(const std::string& name);

  bool operator==(const ModelConfig& other) const;
  bool operator!=(const ModelConfig& other) const { return !(*this == other); }
};

// JSON (de)serialisation through Visit; FromJson validates.
std::string ModelConfigToJson(const ModelConfig& config);
ModelConfig ModelConfigFromJson(const std::string& json);

}  // namespace avatar
