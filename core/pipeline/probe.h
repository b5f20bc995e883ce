#pragma once
// Stand-ins for measuring the network without a photo (the quality ladder's estimates, the
// benchmarks): a synthetic aligned portrait, and an I_exp source that shows one fixed image.

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/pipeline/source_fit.h"

namespace avatar {

// I_exp of a stand-in: the same image for every expression it accepts (resized to the size asked
// for: area when shrinking, cubic when enlarging) and fixed morphable coefficients for a network
// with expression bases.
class FixedExpressionSource : public ExpressionImageSource {
 public:
  // `kind`: the Kind() tag. `own_expression_only`: refuse (InvalidInput) any expression other than
  // the portrait's own (no controls, no coefficients); otherwise every expression shows `bgr`.
  FixedExpressionSource(cv::Mat bgr, std::vector<float> beta, std::string kind, bool own_expression_only);
  cv::Mat Render(const Expression& expression, int size) const override;
  std::vector<float> Coefficients(const Expression& expression) const override;
  std::vector<std::string> ControlNames() const override { return {}; }
  std::string Kind() const override { return kind_; }
  std::string Serialize() const override { return {}; }

 private:
  void Check(const Expression& expression) const;
  cv::Mat bgr_;
  std::vector<float> beta_;
  std::string kind_;
  bool own_expression_only_ = false;
};

// A synthetic aligned 512 portrait: a face-like oval with eyes and mouth on black.
cv::Mat ProbePortraitImage();

// The probe as reconstruction takes it: the aligned portrait (full matte, no eye/mouth mask) ...
face::AlignedPortrait ProbePortrait();
// ... and its fit: the frontal camera C_front and a FixedExpressionSource showing the probe, with
// `expression_coefficients` zeros as beta (0 for a network without expression bases).
SourceFit ProbeFit(int expression_coefficients);

}  // namespace avatar
