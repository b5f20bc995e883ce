#pragma once
// I_exp for the session from the morphable model: the source's identity (alpha, scale) and
// texture with a target expression at the fixed frontal camera C_front, black background
// (morphable::RenderExpressionImage), as the training data renders it (dataset_build_items.cc: the
// target frame's own beta). The target beta is ExpressionBeta of the Expression: {} is the
// portrait's fitted expression, driver coefficients pass through unchanged.
// Kind "morphable": avatar files store the fit and the texture; loading needs the same
// morphable model (the default one, found through DataPaths).

#include <memory>
#include <string>
#include <vector>

#include "core/morphable/morphable.h"
#include "core/pipeline/source_fit.h"

namespace avatar {

// THE conversion of an Expression (expression.h) into morphable expression coefficients for a
// portrait whose fit has `fit_beta`:
//   beta = (coefficients_absolute ? 0 : fit_beta) + coefficients + sum(value * control direction).
// Used by the morphable preview and by the neural session's I_exp, so both show the same face.
// Throws InvalidInput (unknown control, non-finite value, coefficient count other than the
// model's, fit_beta of the wrong size).
morphable::Beta ExpressionBeta(const morphable::MorphableModel& model, const morphable::Beta& fit_beta,
                               const Expression& expression);

class MorphableExpressionSource : public ExpressionImageSource {
 public:
  // `model` must outlive the source (LoadDefaultModel's model lives for the process).
  MorphableExpressionSource(const morphable::MorphableModel& model, morphable::FitResult fit,
                            morphable::Texture texture);
  // I_exp of Coefficients(expression). Throws InvalidInput for unknown controls, non-finite
  // values or a wrong coefficient count.
  cv::Mat Render(const Expression& expression, int size) const override;
  std::vector<std::string> ControlNames() const override;
  int CoefficientCount() const override { return model_.num_expression(); }
  // The target beta Render uses: ExpressionBeta(model, fit beta, expression).
  morphable::Beta Coefficients(const Expression& expression) const override;
  std::string Kind() const override { return "morphable"; }
  std::string Serialize() const override;
  // Rebuilds a source from Serialize() bytes with the default morphable model. Throws
  // ModelLoad (malformed bytes, other model) or MissingData (model not installed).
  static std::shared_ptr<const ExpressionImageSource> Load(const std::string& bytes);

  const morphable::FitResult& fit() const { return fit_; }

 private:
  const morphable::MorphableModel& model_;
  morphable::FitResult fit_;
  morphable::Texture texture_;
};

}  // namespace avatar
