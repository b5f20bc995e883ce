#pragma once
// What the network needs of a portrait besides its aligned image: the source camera and the
// renderer of I_exp for the portrait's identity. The source analysis produces it, the session
// consumes it, avatar files store it; it depends on neither of them.

#include <array>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/pipeline/expression.h"

namespace avatar {

// Renders I_exp: the source identity with a target expression at the fixed frontal camera, black
// background (the morphable model's job; tests plug in synthetic sources).
class ExpressionImageSource {
 public:
  virtual ~ExpressionImageSource() = default;
  // [size,size] CV_8UC3 BGR of the whole Expression (controls, coefficients, absolute). Throws
  // InvalidInput for unknown control names or a wrong coefficient count. Must be thread-safe.
  virtual cv::Mat Render(const Expression& expression, int size) const = 0;
  // Names of the controls Render understands.
  virtual std::vector<std::string> ControlNames() const = 0;
  // Length of Expression::coefficients Render understands (0 = coefficients are not supported).
  virtual int CoefficientCount() const { return 0; }
  // The morphable expression coefficients beta of the whole Expression, the face Render shows:
  // what a network with expression bases (ModelConfig expression_model "bases") mixes its T_e
  // from instead of I_exp. Empty (the default) = this source has no morphable coefficients.
  // Throws as Render. Must be thread-safe.
  virtual std::vector<float> Coefficients(const Expression& expression) const {
    (void)expression;
    return {};
  }
  // Type tag and state, stored in avatar files (see RegisterExpressionSourceLoader).
  virtual std::string Kind() const = 0;
  virtual std::string Serialize() const = 0;
};

// Rebuilds a source from Serialize() bytes when an avatar file is loaded.
using ExpressionSourceLoader = std::shared_ptr<const ExpressionImageSource> (*)(const std::string& bytes);
// Registers the loader of a Kind() (call once at start-up, e.g. from a static initialiser). Returns true.
bool RegisterExpressionSourceLoader(const std::string& kind, ExpressionSourceLoader loader);
// The loader registered for `kind`, or null.
ExpressionSourceLoader FindExpressionSourceLoader(const std::string& kind);

// Inputs of the network part of reconstruction besides the aligned portrait.
struct SourceFit {
  std::array<float, 25> camera{};                            // source camera C_s as an EG3D label
  std::shared_ptr<const ExpressionImageSource> expressions;  // I_exp renderer for this identity
};

}  // namespace avatar
