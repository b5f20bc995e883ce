#include "core/pipeline/morphable_expression_source.h"

#include <cmath>
#include <cstring>

#include <nlohmann/json.hpp>

#include "core/io/data_paths.h"
#include "core/util/error.h"

namespace avatar {

namespace {

const bool kRegistered = RegisterExpressionSourceLoader("morphable", &MorphableExpressionSource::Load);

std::string MatBytes(const cv::Mat& m) {
  if (m.empty()) return {};
  const cv::Mat c = m.isContinuous() ? m : m.clone();
  return std::string(reinterpret_cast<const char*>(c.data), c.total() * c.elemSize());
}

}  // namespace

morphable::Beta ExpressionBeta(const morphable::MorphableModel& model, const morphable::Beta& fit_beta,
                               const Expression& expression) {
  const int k = model.num_expression();
  AVATAR_CHECK_INPUT(static_cast<int>(fit_beta.size()) == k)
      << "the fit has " << fit_beta.size() << " expression coefficients, the morphable model has " << k;
  morphable::Beta beta = expression.coefficients_absolute ? model.ZeroBeta() : fit_beta;
  const std::vector<float>& coefficients = expression.coefficients;
  if (!coefficients.empty()) {
    AVATAR_CHECK_INPUT(static_cast<int>(coefficients.size()) == k)
        << "expression has " << coefficients.size() << " coefficients, the morphable model has " << k;
    for (int i = 0; i < k; ++i) {
      AVATAR_CHECK_INPUT(std::isfinite(coefficients[i])) << "expression coefficient " << i << " is not finite";
      beta[i] += coefficients[i];
    }
  }
  std::map<std::string, float> controls;
  for (const auto& [name, value] : expression.controls) {
    if (value != 0.0f) controls[name] = value;
  }
  // An explicit 0 of any name is neutral; other names are checked (and rejected when unknown) here.
  if (!controls.empty()) {
    const morphable::Beta offset = model.ExpressionFromControls(controls);
    for (int i = 0; i < k; ++i) beta[i] += offset[i];
  }
  return beta;
}

MorphableExpressionSource::MorphableExpressionSource(const morphable::MorphableModel& model, morphable::FitResult fit,
                                                     morphable::Texture texture)
    : model_(model), fit_(std::move(fit)), texture_(std::move(texture)) {
  (void)kRegistered;
}

cv::Mat MorphableExpressionSource::Render(const Expression& expression, int size) const {
  AVATAR_CHECK_INPUT(size >= 8 && size <= 4096) << "expression image size must be 8..4096, got " << size;
  const morphable::Beta beta = Coefficients(expression);
  morphable::RenderOptions options;
  options.supersample = 2;  // antialiased edges: the encoder sees no stair steps
  const morphable::RenderResult r =
      morphable::RenderExpressionImage(model_, fit_, texture_, beta, cv::Size(size, size), options);
  cv::Mat bgr;
  r.image.convertTo(bgr, CV_8UC3, 255.0);
  return bgr;
}

morphable::Beta MorphableExpressionSource::Coefficients(const Expression& expression) const {
  return ExpressionBeta(model_, fit_.beta, expression);
}

std::vector<std::string> MorphableExpressionSource::ControlNames() const {
  std::vector<std::string> names;
  for (const auto& c : model_.controls()) names.push_back(c.name);
  return names;
}

std::string MorphableExpressionSource::Serialize() const {
  nlohmann::json j;
  j["alpha"] = fit_.alpha;
  j["beta"] = fit_.beta;
  j["scale"] = fit_.scale;
  j["rotation"] = std::vector<double>(fit_.rotation.val, fit_.rotation.val + 9);
  j["translation"] = std::vector<double>(fit_.translation.val, fit_.translation.val + 3);
  j["camera"] = std::vector<float>(fit_.camera.begin(), fit_.camera.end());
  j["image_size"] = {fit_.image_size.width, fit_.image_size.height};
  std::vector<float> colors;
  for (const auto& c : texture_.vertex_colors) colors.insert(colors.end(), {c[0], c[1], c[2]});
  j["vertex_colors"] = colors;
  j["uv_size"] = texture_.uv_image.empty() ? 0 : texture_.uv_image.rows;
  const std::string header = j.dump();
  const std::string uv = MatBytes(texture_.uv_image), visible = MatBytes(texture_.uv_visible);
  std::string out;
  const uint64_t sizes[3] = {header.size(), uv.size(), visible.size()};
  out.append(reinterpret_cast<const char*>(sizes), sizeof(sizes));
  out += header;
  out += uv;
  out += visible;
  return out;
}

std::shared_ptr<const ExpressionImageSource> MorphableExpressionSource::Load(const std::string& bytes) {
  uint64_t sizes[3];
  if (bytes.size() < sizeof(sizes)) throw ModelLoad("morphable expression source: data is truncated");
  std::memcpy(sizes, bytes.data(), sizeof(sizes));
  if (sizes[0] > bytes.size() || sizes[1] > bytes.size() || sizes[2] > bytes.size() ||
      sizeof(sizes) + sizes[0] + sizes[1] + sizes[2] != bytes.size()) {
    throw ModelLoad("morphable expression source: data is truncated or malformed");
  }
  const morphable::MorphableModel& model = morphable::LoadDefaultModel(DataPaths::Resolve());
  morphable::FitResult fit;
  morphable::Texture texture;
  try {
    const nlohmann::json j = nlohmann::json::parse(bytes.substr(sizeof(sizes), sizes[0]));
    fit.alpha = j.at("alpha").get<std::vector<float>>();
    fit.beta = j.at("beta").get<std::vector<float>>();
    fit.scale = j.at("scale").get<float>();
    const auto rot = j.at("rotation").get<std::vector<double>>();
    const auto tr = j.at("translation").get<std::vector<double>>();
    const auto cam = j.at("camera").get<std::vector<float>>();
    const auto size = j.at("image_size").get<std::vector<int>>();
    const auto colors = j.at("vertex_colors").get<std::vector<float>>();
    const int uv_size = j.at("uv_size").get<int>();
    if (rot.size() != 9 || tr.size() != 3 || cam.size() != fit.camera.size() || size.size() != 2 ||
        colors.size() % 3 != 0) {
      throw ModelLoad("morphable expression source: malformed fit");
    }
    if (static_cast<int>(fit.alpha.size()) != model.num_identity() ||
        static_cast<int>(fit.beta.size()) != model.num_expression()) {
      throw ModelLoad("morphable expression source: the avatar was fitted with a different morphable model");
    }
    std::copy(rot.begin(), rot.end(), fit.rotation.val);
    std::copy(tr.begin(), tr.end(), fit.translation.val);
    std::copy(cam.begin(), cam.end(), fit.camera.begin());
    fit.image_size = cv::Size(size[0], size[1]);
    for (size_t i = 0; i < colors.size(); i += 3)
      texture.vertex_colors.emplace_back(colors[i], colors[i + 1], colors[i + 2]);
    if (uv_size > 0) {
      if (sizes[1] != static_cast<uint64_t>(uv_size) * uv_size * 3 * sizeof(float) ||
          sizes[2] != static_cast<uint64_t>(uv_size) * uv_size) {
        throw ModelLoad("morphable expression source: texture size mismatch");
      }
      texture.uv_image.create(uv_size, uv_size, CV_32FC3);
      std::memcpy(texture.uv_image.data, bytes.data() + sizeof(sizes) + sizes[0], sizes[1]);
      texture.uv_visible.create(uv_size, uv_size, CV_8UC1);
      std::memcpy(texture.uv_visible.data, bytes.data() + sizeof(sizes) + sizes[0] + sizes[1], sizes[2]);
    }
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(std::string("morphable expression source: malformed fit: ") + e.what());
  }
  return std::make_shared<MorphableExpressionSource>(model, std::move(fit), std::move(texture));
}

}  // namespace avatar
