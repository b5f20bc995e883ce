#include "core/morphable/morphable_model.h"

#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <mutex>

#include <nlohmann/json.hpp>

#include "core/io/atomic_file.h"
#include "core/io/resources.h"
#include "core/util/error.h"

namespace avatar::morphable {

namespace {

constexpr char kMagic[8] = {'A', 'V', 'M', 'O', 'R', 'P', 'H', '\0'};
constexpr size_t kCoords = static_cast<size_t>(kVertexCount) * 3;

void CheckFinite(const std::vector<float>& v, const char* what) {
  for (float x : v) AVATAR_CHECK_INPUT(std::isfinite(x)) << "morphable model: non-finite value in " << what;
}

// out[row] += sum_k basis[row, k] * coeff[k]
void AddBasis(const std::vector<float>& basis, const std::vector<float>& coeff, std::vector<float>& out) {
  const size_t k = coeff.size();
  if (k == 0) return;
  for (size_t r = 0; r < kCoords; ++r) {
    const float* row = &basis[r * k];
    double acc = 0.0;
    for (size_t c = 0; c < k; ++c) acc += static_cast<double>(row[c]) * coeff[c];
    out[r] += static_cast<float>(acc);
  }
}

}  // namespace

const std::vector<std::string>& RequiredControlNames() {
  static const std::vector<std::string> names = {"jawOpen",   "smile",     "frown",     "pucker",     "mouthWide",
                                                 "browRaise", "browFrown", "blinkLeft", "blinkRight", "eyesWide"};
  return names;
}

MorphableModel::MorphableModel(Topology topology, std::vector<float> mean, std::vector<float> identity_basis,
                               std::vector<float> identity_std, std::vector<float> expression_basis,
                               std::vector<float> expression_std)
    : topology_(std::move(topology)),
      mean_(std::move(mean)),
      identity_basis_(std::move(identity_basis)),
      identity_std_(std::move(identity_std)),
      expression_basis_(std::move(expression_basis)),
      expression_std_(std::move(expression_std)) {
  AVATAR_CHECK_INPUT(mean_.size() == kCoords) << "morphable model: mean must have " << kCoords << " values";
  AVATAR_CHECK_INPUT(identity_basis_.size() == kCoords * identity_std_.size())
      << "morphable model: identity basis size " << identity_basis_.size() << " does not match " << identity_std_.size()
      << " components";
  AVATAR_CHECK_INPUT(expression_basis_.size() == kCoords * expression_std_.size())
      << "morphable model: expression basis size " << expression_basis_.size() << " does not match "
      << expression_std_.size() << " components";
  AVATAR_CHECK_INPUT(topology_.canonical_cm.size() == static_cast<size_t>(kVertexCount))
      << "morphable model: topology must have " << kVertexCount << " vertices";
  CheckFinite(mean_, "mean");
  CheckFinite(identity_basis_, "identity basis");
  CheckFinite(identity_std_, "identity std");
  CheckFinite(expression_basis_, "expression basis");
  CheckFinite(expression_std_, "expression std");
  for (float s : identity_std_) AVATAR_CHECK_INPUT(s > 0.0f) << "morphable model: identity std must be > 0";
  for (float s : expression_std_) AVATAR_CHECK_INPUT(s > 0.0f) << "morphable model: expression std must be > 0";
}

std::vector<cv::Point3f> MorphableModel::Vertices(const Alpha& alpha, const Beta& beta) const {
  AVATAR_CHECK_INPUT(alpha.empty() || alpha.size() == identity_std_.size())
      << "alpha has " << alpha.size() << " values, the model has " << identity_std_.size() << " identity components";
  AVATAR_CHECK_INPUT(beta.empty() || beta.size() == expression_std_.size())
      << "beta has " << beta.size() << " values, the model has " << expression_std_.size() << " expression components";
  std::vector<float> flat = mean_;
  AddBasis(identity_basis_, alpha, flat);
  AddBasis(expression_basis_, beta, flat);
  std::vector<cv::Point3f> out(kVertexCount);
  for (int i = 0; i < kVertexCount; ++i) out[i] = {flat[3 * i], flat[3 * i + 1], flat[3 * i + 2]};
  return out;
}

torch::Tensor MorphableModel::VerticesTensor(const torch::Tensor& alpha, const torch::Tensor& beta) const {
  AVATAR_CHECK_INPUT(alpha.dim() == 2 && alpha.size(1) == num_identity())
      << "alpha must be [B," << num_identity() << "], got " << alpha.sizes();
  AVATAR_CHECK_INPUT(beta.dim() == 2 && beta.size(1) == num_expression() && beta.size(0) == alpha.size(0))
      << "beta must be [B," << num_expression() << "] with the batch of alpha, got " << beta.sizes();
  const auto opts = alpha.options();
  auto from = [&](const std::vector<float>& v, int64_t rows, int64_t cols) {
    return torch::from_blob(const_cast<float*>(v.data()), {rows, cols}, torch::kFloat32).to(opts, false, true);
  };
  const int64_t n = static_cast<int64_t>(kCoords);
  torch::Tensor flat = from(mean_, 1, n);  // [1,N]
  if (num_identity() > 0) flat = flat + torch::matmul(alpha, from(identity_basis_, n, num_identity()).t());
  if (num_expression() > 0)
    flat = flat + torch::matmul(beta.to(opts), from(expression_basis_, n, num_expression()).t());
  return flat.expand({alpha.size(0), n}).reshape({alpha.size(0), kVertexCount, 3});
}

void MorphableModel::SetControls(std::vector<NamedControl> controls) {
  for (const auto& c : controls) {
    AVATAR_CHECK_INPUT(c.direction.size() == expression_std_.size())
        << "control " << c.name << " has " << c.direction.size() << " values, expected " << expression_std_.size();
    CheckFinite(c.direction, "control direction");
  }
  controls_ = std::move(controls);
}

const NamedControl& MorphableModel::Control(const std::string& name) const {
  for (const auto& c : controls_) {
    if (c.name == name) return c;
  }
  std::string known;
  for (const auto& c : controls_) known += (known.empty() ? "" : ", ") + c.name;
  throw InvalidInput("unknown expression control '" + name + "'; known controls: " + known);
}

Beta MorphableModel::ExpressionFromControls(const std::map<std::string, float>& values) const {
  Beta beta = ZeroBeta();
  for (const auto& [name, value] : values) {
    AVATAR_CHECK_INPUT(std::isfinite(value)) << "expression control " << name << " must be finite";
    const NamedControl& c = Control(name);
    for (size_t k = 0; k < beta.size(); ++k) beta[k] += value * c.direction[k];
  }
  return beta;
}

void MorphableModel::Save(const std::filesystem::path& path) const {
  nlohmann::json meta;
  meta["format_version"] = kModelFormatVersion;
  meta["vertices"] = kVertexCount;
  meta["identity_components"] = num_identity();
  meta["expression_components"] = num_expression();
  meta["units_per_cm"] = kUnitsPerCm;
  meta["provenance"] = provenance_;
  meta["build_info"] = nlohmann::json::parse(build_info_json_.empty() ? "{}" : build_info_json_);
  nlohmann::json controls = nlohmann::json::array();
  for (const auto& c : controls_) {
    controls.push_back(
        {{"name", c.name}, {"label", c.label}, {"description", c.description}, {"direction", c.direction}});
  }
  meta["controls"] = controls;
  const std::string text = meta.dump();
  std::string bytes(kMagic, sizeof(kMagic));
  auto put_u32 = [&](uint32_t v) { bytes.append(reinterpret_cast<const char*>(&v), 4); };
  put_u32(kModelFormatVersion);
  put_u32(static_cast<uint32_t>(text.size()));
  bytes += text;
  for (const auto* arr : {&mean_, &identity_basis_, &identity_std_, &expression_basis_, &expression_std_}) {
    bytes.append(reinterpret_cast<const char*>(arr->data()), arr->size() * sizeof(float));
  }
  WriteBytesAtomically(path, bytes);
}

MorphableModel MorphableModel::Load(const std::filesystem::path& path, const Topology& topology) {
  const std::string bytes = ReadFileBytes(path);
  const std::string name = path.string();
  AVATAR_CHECK_AS(ModelLoad, bytes.size() >= 16 && std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) == 0)
      << name << " is not an Avatar Studio morphable model; rebuild it with `avatar-studio build-morphable`";
  uint32_t version = 0, json_len = 0;
  std::memcpy(&version, bytes.data() + 8, 4);
  std::memcpy(&json_len, bytes.data() + 12, 4);
  AVATAR_CHECK_AS(ModelLoad, version == kModelFormatVersion)
      << name << " has format version " << version << ", this build reads version " << kModelFormatVersion
      << "; rebuild it with `avatar-studio build-morphable`";
  AVATAR_CHECK_AS(ModelLoad, 16 + static_cast<size_t>(json_len) <= bytes.size()) << name << " is truncated";
  nlohmann::json meta;
  try {
    meta = nlohmann::json::parse(bytes.substr(16, json_len));
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(name + ": corrupt header (" + e.what() + ")");
  }
  size_t kid = 0, kexp = 0;
  try {
    AVATAR_CHECK_AS(ModelLoad, meta.at("vertices").get<int>() == kVertexCount)
        << name << ": the model is not on the " << kVertexCount << "-vertex topology";
    kid = meta.at("identity_components").get<size_t>();
    kexp = meta.at("expression_components").get<size_t>();
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(name + ": incomplete header (" + e.what() + ")");
  }
  AVATAR_CHECK_AS(ModelLoad, kid < 10000 && kexp < 10000) << name << ": implausible component counts";
  const size_t floats = kCoords * (1 + kid + kexp) + kid + kexp;
  AVATAR_CHECK_AS(ModelLoad, bytes.size() == 16 + json_len + floats * sizeof(float))
      << name << " has " << bytes.size() << " bytes, expected " << 16 + json_len + floats * sizeof(float)
      << "; the file is truncated or corrupt";
  const char* p = bytes.data() + 16 + json_len;
  auto take = [&](size_t n) {
    std::vector<float> v(n);
    std::memcpy(v.data(), p, n * sizeof(float));
    p += n * sizeof(float);
    return v;
  };
  std::vector<float> mean = take(kCoords);
  std::vector<float> id_basis = take(kCoords * kid);
  std::vector<float> id_std = take(kid);
  std::vector<float> exp_basis = take(kCoords * kexp);
  std::vector<float> exp_std = take(kexp);
  try {
    MorphableModel model(topology, std::move(mean), std::move(id_basis), std::move(id_std), std::move(exp_basis),
                         std::move(exp_std));
    std::vector<NamedControl> controls;
    for (const auto& c : meta.value("controls", nlohmann::json::array())) {
      controls.push_back({c.at("name").get<std::string>(), c.at("label").get<std::string>(),
                          c.at("description").get<std::string>(), c.at("direction").get<std::vector<float>>()});
    }
    model.SetControls(std::move(controls));
    model.provenance_ = meta.value("provenance", std::string());
    model.build_info_json_ = meta.value("build_info", nlohmann::json::object()).dump();
    return model;
  } catch (const InvalidInput& e) {
    throw ModelLoad(name + ": " + e.what());
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(name + ": corrupt controls (" + e.what() + ")");
  }
}

std::filesystem::path DefaultModelPath() {
  if (const char* env = std::getenv("AVATAR_MORPHABLE_MODEL"); env != nullptr && env[0] != '\0') return env;
  return ResourcePath(kDefaultModelFile);
}

const MorphableModel& LoadDefaultModel(const DataPaths& paths) {
  static std::mutex mutex;
  static std::map<std::string, MorphableModel> cache;
  std::lock_guard<std::mutex> lock(mutex);
  const auto path = DefaultModelPath();
  const std::string key = path.string() + "|" + paths.Root().string();
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  AVATAR_CHECK_AS(MissingData, std::filesystem::exists(path))
      << "the morphable face model " << path.string()
      << " is missing; build it with `avatar-studio build-morphable` or set AVATAR_MORPHABLE_MODEL";
  const Topology& topo = LoadTopology(paths);
  return cache.emplace(key, MorphableModel::Load(path, topo)).first->second;
}

}  // namespace avatar::morphable
