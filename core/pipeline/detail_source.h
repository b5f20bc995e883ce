#pragma once
// The source-guided detail path over any frame source of a reconstructed portrait (the neural
// avatar by default): each frame is the base source's frame with the photo's own pixels warped
// onto the face where the photo saw it (core/compose/face_detail.h), feathered into the base
// frame elsewhere. Labelled as the base source plus the detail path, so every output says which
// path rendered it.

#include <memory>
#include <string>
#include <vector>

#include "core/compose/face_detail.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/source_analysis.h"

namespace avatar {

// The detail paths a frame can take: "face" (the photo warped through the face mesh) or "off"
// (the base source alone).
const std::vector<std::string>& DetailModes();
// Throws InvalidOptions naming the choices for anything else.
void ValidateDetailMode(const std::string& mode);

class DetailFrameSource : public FrameSource {
 public:
  // `base` renders the head; `analysis` is the portrait's (its fit, aligned photo, matte and
  // eye/mouth mask); its morphable model must outlive the source. Throws InvalidInput.
  DetailFrameSource(std::shared_ptr<const FrameSource> base, const SourceAnalysis& analysis,
                    const compose::FaceDetailOptions& options = {});

  std::string Label() const override;
  bool SupportsPose() const override { return base_->SupportsPose(); }
  std::vector<std::string> ExpressionControls() const override { return base_->ExpressionControls(); }
  int CoefficientCount() const override { return base_->CoefficientCount(); }
  ViewPose SourcePose() const override { return base_->SourcePose(); }
  SourceOverlay Overlay() const override { return base_->Overlay(); }
  RenderedFrame Render(const FrameRequest& request, RunContext& ctx) const override;

  // The warp of one request alone (for tests and measurements).
  compose::FaceWarp Warp(const FrameRequest& request) const;
  const FrameSource& base() const { return *base_; }

 private:
  std::shared_ptr<const FrameSource> base_;
  const morphable::MorphableModel* model_;
  compose::FaceDetail detail_;
};

// The label suffix of frames with the detail path.
inline constexpr const char* kDetailLabel = " + the photo's detail on the face";

}  // namespace avatar
