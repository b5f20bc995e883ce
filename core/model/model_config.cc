#include "core/model/model_config.h"

#include <algorithm>

#include <nlohmann/json.hpp>

#include "core/util/error.h"
#include "core/util/options.h"

namespace avatar {

namespace {

bool IsPowerOfTwo(int v) { return v > 0 && (v & (v - 1)) == 0; }

}  // namespace

void ModelConfig::Validate() const {
  AVATAR_CHECK_OPTION(encoder == "mit_b0" || encoder == "mobilenet_v2")
      << "model config '" << name << "': encoder must be mit_b0 or mobilenet_v2, got '" << encoder << "'";
  AVATAR_CHECK_OPTION(expression_model == "encoder" || expression_model == "bases")
      << "model config '" << name << "': expression_model must be encoder or bases, got '" << expression_model << "'";
  AVATAR_CHECK_OPTION(expression_coefficients >= 1 && expression_coefficients <= 1024)
      << "model config '" << name << "': expression_coefficients must be 1..1024, got " << expression_coefficients;
  AVATAR_CHECK_OPTION(encoder_widths.size() == 4 && encoder_depths.size() == 4 && encoder_heads.size() == 4 &&
                      encoder_sr_ratios.size() == 4)
      << "model config '" << name << "': the encoder needs exactly 4 stages";
  for (int s = 0; s < 4; ++s) {
    AVATAR_CHECK_OPTION(encoder_widths[s] > 0 && encoder_depths[s] > 0 && encoder_heads[s] > 0 &&
                        encoder_sr_ratios[s] > 0)
        << "model config '" << name << "': stage " << s << " sizes must be positive";
    AVATAR_CHECK_OPTION(encoder_widths[s] % encoder_heads[s] == 0)
        << "model config '" << name << "': stage " << s << " width " << encoder_widths[s] << " is not divisible by its "
        << encoder_heads[s] << " heads";
  }
  AVATAR_CHECK_OPTION(image_size >= 32 && image_size % 32 == 0 && image_size <= 2048)
      << "model config '" << name << "': image_size must be a multiple of 32 in 32..2048, got " << image_size;
  const int stage4 = image_size / 32;
  AVATAR_CHECK_OPTION(stage4 % encoder_sr_ratios[3] == 0 && (image_size / 16) % encoder_sr_ratios[2] == 0 &&
                      (image_size / 8) % encoder_sr_ratios[1] == 0 && (image_size / 4) % encoder_sr_ratios[0] == 0)
      << "model config '" << name << "': spatial-reduction ratios must divide each stage's resolution";
  AVATAR_CHECK_OPTION(encoder_mlp_ratio > 0 && decoder_dim > 0 && head_width > 0 && head_mid_width > 0 &&
                      plane_channels >= 3 && decoder_hidden > 0 && upsampler_width > 0)
      << "model config '" << name << "': widths must be positive (plane_channels >= 3 for RGB)";
  AVATAR_CHECK_OPTION(render_size >= 4 && render_size <= 1024)
      << "model config '" << name << "': render_size must be 4..1024, got " << render_size;
  AVATAR_CHECK_OPTION(num_coarse >= 4 && num_importance >= 0)
      << "model config '" << name << "': need num_coarse >= 4 and num_importance >= 0";
  AVATAR_CHECK_OPTION(IsPowerOfTwo(sr_size) && sr_size >= 16 && sr_size <= 2048 && sr_size >= render_size)
      << "model config '" << name << "': sr_size must be a power of two in 16..2048 and >= render_size";
  AVATAR_CHECK_OPTION(sr_channel_multiplier > 0 && sr_max_channels > 0 && sr_style_dim > 0 && disc_max_channels > 0)
      << "model config '" << name << "': SR/discriminator widths must be positive";
}

int ModelConfig::SrChannels(int resolution) const {
  const long wanted = 16384L * sr_channel_multiplier / std::max(resolution, 1);
  return static_cast<int>(std::max(1L, std::min<long>(sr_max_channels, wanted)));
}

ModelConfig ModelConfig::Paper() { return ModelConfig{}; }

ModelConfig ModelConfig::Lite() {
  ModelConfig c;
  c.name = "lite";
  c.image_size = 256;
  c.render_size = 64;
  c.num_coarse = 24;
  c.num_importance = 24;
  c.sr_size = 256;
  c.sr_channel_multiplier = 1;
  c.sr_max_channels = 128;
  c.sr_style_dim = 128;
  c.disc_max_channels = 128;
  return c;
}

ModelConfig ModelConfig::Cpu() {
  ModelConfig c;
  c.name = "cpu";
  c.encoder = "mobilenet_v2";
  c.image_size = 128;
  c.render_size = 32;
  c.num_coarse = 24;
  c.num_importance = 24;
  c.sr_size = 128;
  c.sr_channel_multiplier = 1;
  c.sr_max_channels = 64;
  c.sr_style_dim = 64;
  c.disc_max_channels = 64;
  return c;
}

ModelConfig ModelConfig::Tiny() {
  ModelConfig c;
  c.name = "tiny";
  c.image_size = 64;
  c.encoder_widths = {8, 16, 24, 32};
  c.encoder_depths = {1, 1, 1, 1};
  c.encoder_heads = {1, 1, 2, 2};
  c.encoder_sr_ratios = {4, 2, 2, 1};
  c.encoder_mlp_ratio = 2;
  c.decoder_dim = 32;
  c.head_width = 32;
  c.head_mid_width = 16;
  c.plane_channels = 8;
  c.decoder_hidden = 16;
  c.upsampler_width = 16;
  c.render_size = 16;
  c.num_coarse = 8;
  c.num_importance = 8;
  c.sr_size = 32;
  c.sr_channel_multiplier = 1;
  c.sr_max_channels = 16;
  c.sr_style_dim = 16;
  c.disc_max_channels = 16;
  return c;
}

ModelConfig ModelConfig::FromName(const std::string& name) {
  if (name == "paper") return Paper();
  if (name == "lite") return Lite();
  if (name == "tiny") return Tiny();
  if (name == "cpu") return Cpu();
  throw InvalidOptions("unknown model config '" + name + "' (paper, lite, cpu or tiny)");
}

bool ModelConfig::operator==(const ModelConfig& other) const {
  return ModelConfigToJson(*this) == ModelConfigToJson(other);
}

std::string ModelConfigToJson(const ModelConfig& config) { return options::ToJson(config).dump(); }

ModelConfig ModelConfigFromJson(const std::string& json) {
  ModelConfig config;
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(json);
  } catch (const nlohmann::json::exception& e) {
    throw InvalidOptions(std::string("model config is not valid JSON: ") + e.what());
  }
  options::FromJson(config, j);
  config.Validate();
  return config;
}

}  // namespace avatar
