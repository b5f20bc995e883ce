#pragma once
// The one expression type of core/pipeline: what the studio's sliders, a driving video and the
// CLI flags ask for, what every frame source renders and what the neural session turns into
// I_exp. Expressions are morphable-model expression coefficients (beta); named controls are a
// way of writing them (beta += value * the control's direction), never the other way round.
// ExpressionBeta (core/pipeline/morphable_expression_source.h) is the one function that turns an
// Expression into the beta of a fitted portrait; the morphable preview and the neural session's
// I_exp both call it.

#include <map>
#include <string>
#include <vector>

namespace avatar {

// beta = (coefficients_absolute ? 0 : the portrait's fitted beta) + coefficients
//        + sum over controls of value * direction.
// So {} is the portrait's own expression; a driver measured as coefficients passes them on
// unchanged (an offset from its neutral frame in relative transfer, the whole expression in
// absolute transfer).
struct Expression {
  // Named controls (jawOpen, smile, ...) -> value, usually in [0,1]; missing names are 0.
  std::map<std::string, float> controls;
  // Raw morphable expression coefficients (as many as the model has), or empty for none.
  std::vector<float> coefficients{};
  // True: the expression starts from the model's zero expression instead of the portrait's own.
  bool coefficients_absolute = false;

  float Get(const std::string& name) const {
    auto it = controls.find(name);
    return it == controls.end() ? 0.0f : it->second;
  }
  bool operator==(const Expression& o) const {
    return controls == o.controls && coefficients == o.coefficients && coefficients_absolute == o.coefficients_absolute;
  }
  bool operator!=(const Expression& o) const { return !(*this == o); }
  // Canonical text form, the session's cache key: "jawOpen=0.5,smile=0.2" for controls (zeros
  // left out), then "|c=..." with every coefficient (round-trip precision) and "|absolute" when
  // set. The neutral expression is "".
  std::string Key() const;
};

}  // namespace avatar
