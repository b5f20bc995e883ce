#pragma once
// I_exp for the session from the morphable model: the source's identity (alpha, scale) and
// texture with a target expression at the fixed frontal camera C_front, black background
// (morphable::RenderExpressionImage). Expression controls are the model's named controls
// (jawOpen, smile, ...): beta_target = sum value * direction, so {} is the neutral face.
// Kind "morphable": avatar files store the fit and the texture; loading needs the same
// morphable model (the default one, found through DataPaths).

#include <memory>
#include <string>
#include <vector>

#include "core/morphable/morphable.h"
#include "core/pipeline/session.h"

namespace avatar {

class MorphableExpressionSource : public ExpressionImageSource {
 public:
  // `model` must outlive the source (LoadDefaultModel's model lives for the process).
  MorphableExpressionSource(const morphable::MorphableModel& model, morphable::FitResult fit,
                            morphable::Texture texture);
  // Throws InvalidInput for unknown controls or non-finite values.
  cv::Mat Render(const Expression& expression, int size) const override;
  std::vector<std::string> ControlNames() const override;
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
