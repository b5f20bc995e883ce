#pragma once
// The linear morphable face model S = mean + B_id * alpha + B_exp * beta on the MediaPipe
// topology (468 vertices), with per-component standard deviations and named expression
// controls (directions in beta space).
//
// Units and frame: model coordinates live in the EG3D world frame of core/render (y up, the face
// looks towards +z, the head centre near the origin, inside [-0.5,0.5]^3). One model unit is
// kUnitsPerCm^-1 centimetres: the canonical mesh (in cm) times kUnitsPerCm, so an average face is
// about 0.39 units wide (ear to ear) and eye centres are ~0.16 apart. A fit adds a scale factor
// (FitResult::scale) that maps the model into the world of the fitted 25-float camera label.

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <torch/torch.h>
#include <opencv2/core.hpp>

#include "core/io/data_paths.h"
#include "core/morphable/topology.h"

namespace avatar::morphable {

// Model units per centimetre of the canonical mesh.
inline constexpr double kUnitsPerCm = 0.025;
// Current model file format version (see MorphableModel::Save).
inline constexpr uint32_t kModelFormatVersion = 1;
// Relative path of the committed model under the source tree's resources/ (or the install's share/).
inline constexpr const char* kDefaultModelFile = "morphable/face_model.avmm";

using Alpha = std::vector<float>;  // identity coefficients, [num_identity()]
using Beta = std::vector<float>;   // expression coefficients, [num_expression()]

// One named expression control: a documented direction in beta space.
struct NamedControl {
  std::string name;         // CLI/file name, e.g. "jawOpen".
  std::string label;        // Friendly GUI label, e.g. "Jaw open".
  std::string description;  // What it does and how it was derived.
  Beta direction;           // beta change for control value 1.0, [num_expression()]
};

// The names every model provides (in GUI order).
const std::vector<std::string>& RequiredControlNames();

class MorphableModel {
 public:
  MorphableModel() = default;

  // Builds a model from raw arrays (used by the builder and tests). Shapes: mean [468*3],
  // identity_basis [468*3, Kid] row-major (column k = component k), identity_std [Kid], likewise for
  // expression. Throws InvalidInput on inconsistent sizes or non-finite values.
  MorphableModel(Topology topology, std::vector<float> mean, std::vector<float> identity_basis,
                 std::vector<float> identity_std, std::vector<float> expression_basis,
                 std::vector<float> expression_std);

  // Reads a model file (format version kModelFormatVersion) and attaches `topology`. Throws Io
  // (unreadable) or ModelLoad (not a model file, other version, inconsistent sizes), naming the file.
  static MorphableModel Load(const std::filesystem::path& path, const Topology& topology);
  // Writes the model atomically. Throws Io.
  void Save(const std::filesystem::path& path) const;

  int num_vertices() const { return kVertexCount; }
  int num_identity() const { return static_cast<int>(identity_std_.size()); }
  int num_expression() const { return static_cast<int>(expression_std_.size()); }
  const Topology& topology() const { return topology_; }
  const std::vector<float>& mean() const { return mean_; }                          // [468*3]
  const std::vector<float>& identity_basis() const { return identity_basis_; }      // [468*3, Kid]
  const std::vector<float>& identity_std() const { return identity_std_; }          // [Kid]
  const std::vector<float>& expression_basis() const { return expression_basis_; }  // [468*3, Kexp]
  const std::vector<float>& expression_std() const { return expression_std_; }      // [Kexp]

  // Zero coefficient vectors of the right sizes.
  Alpha ZeroAlpha() const { return Alpha(num_identity(), 0.0f); }
  Beta ZeroBeta() const { return Beta(num_expression(), 0.0f); }

  // Vertex positions in model units; empty alpha/beta mean zeros. Throws InvalidInput on a size
  // mismatch. Returns 468 points.
  std::vector<cv::Point3f> Vertices(const Alpha& alpha, const Beta& beta) const;
  // Batched tensor version: alpha [B,Kid], beta [B,Kexp] (float32/64, any device) -> [B,468,3].
  torch::Tensor VerticesTensor(const torch::Tensor& alpha, const torch::Tensor& beta) const;

  // Named controls (at least RequiredControlNames()).
  const std::vector<NamedControl>& controls() const { return controls_; }
  void SetControls(std::vector<NamedControl> controls);
  // Throws InvalidInput for an unknown name (the message lists the known ones).
  const NamedControl& Control(const std::string& name) const;
  // beta = sum over entries of value * direction. Throws InvalidInput on unknown names or
  // non-finite values.
  Beta ExpressionFromControls(const std::map<std::string, float>& values) const;

  // Free text saved with the model: how and from what it was built.
  const std::string& provenance() const { return provenance_; }
  void set_provenance(std::string text) { provenance_ = std::move(text); }
  // Build statistics (variance explained etc.), saved with the model as JSON.
  const std::string& build_info_json() const { return build_info_json_; }
  void set_build_info_json(std::string json) { build_info_json_ = std::move(json); }

 private:
  Topology topology_;
  std::vector<float> mean_;
  std::vector<float> identity_basis_;
  std::vector<float> identity_std_;
  std::vector<float> expression_basis_;
  std::vector<float> expression_std_;
  std::vector<NamedControl> controls_;
  std::string provenance_;
  std::string build_info_json_ = "{}";
};

// Where the default model is: $AVATAR_MORPHABLE_MODEL, else ResourcePath(kDefaultModelFile)
// (core/io/resources.h: the install's share/avatar-studio/, else the source tree's resources/).
std::filesystem::path DefaultModelPath();
// Loads the default model with the installed topology. Throws MissingData / ModelLoad with what to do.
const MorphableModel& LoadDefaultModel(const DataPaths& paths);

}  // namespace avatar::morphable
