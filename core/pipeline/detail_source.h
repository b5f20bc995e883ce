#pragma once
// The source-guided detail path over any frame source of a reconstructed portrait (the neural
// avatar by default): each frame is the base source's frame with the photo's own pixels warped
// onto the face where the photo saw it (core/compose/face_detail.h), feathered into the base
// frame elsewhere. Labelled as the base source plus the detail path, so every output says which
// path rendered it.

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/compose/depth_detail.h"
#include "core/compose/edge_matte.h"
#include "core/compose/face_detail.h"
#include "core/pipeline/detail_layers.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/source_analysis.h"

namespace avatar {

struct HeadMesh;

// The detail paths a frame can take: "head" (the photo warped through the face mesh on the
// face, and through the network's own depth on hair, ears and neck), "face" (the face mesh only)
// or "off" (the base source alone).
const std::vector<std::string>& DetailModes();
// Throws InvalidOptions naming the choices for anything else.
void ValidateDetailMode(const std::string& mode);

struct DetailOptions {
  std::string mode = "head";  // head or face (off: do not wrap)
  compose::FaceDetailOptions face;
  compose::DepthDetailOptions depth;
  // Face pixels the photo did not see (the far cheek of a turned head) come from the fitted
  // face's texture (the morphable preview's, which is filled where the photo did not see) instead
  // of the base frame.
  bool face_fill = true;
  // The photo's person edge cleaned of the background colour (compose::RefineEdgeMatte) before
  // either warp or the fill texture reads it.
  bool clean_edges = true;
  compose::EdgeMatteOptions edges;
  // Size of the base render whose depth is the source view's proxy (once per source).
  int source_depth_size = 128;
  // The network's depth is moved along the rays by its median gap to the fitted face mesh at the
  // photo's view (compose::FaceDepthOffset), at the source view and every target view, so that the
  // hair and temples lifted with it turn with the face. Off by default: measured on the franck
  // stills it raises identity at +-30 degrees (0.772 / 0.752 -> 0.803 / 0.765 moving the whole
  // head, 0.797 / 0.764 with reach 0.1), but against real turned frames of the validation clip it
  // costs the composite 0.2-0.5 dB PSNR and 0.002-0.011 SSIM in every yaw bucket
  // (docs/PERFORMANCE.md "Moving the network's depth onto the face"): ground truth decides.
  bool align_depth_to_face = false;
  // How far from the face mesh the move reaches, as a fraction of the image height
  // (compose::FaceOffsetField; <= 0: the whole head moves).
  double align_depth_reach = 0.1;
  // Weights of the fusion net that finishes each frame (core/model/fusion_net.h; "" = the
  // geometric composite is the frame). Frames above kFusionNetSide px get the net's change at
  // that side, scaled up onto the full-size composite.
  std::string fusion;
  // The base source (the network) is asked for a new expression on every Nth frame at most; in
  // between it renders the new view at the last expression it was given (the network keeps that
  // expression's planes: no encoding), under the photo's face at each frame's own expression.
  // 1 = every frame (exports and the studio); live driving uses 3 (LiveOptions).
  int base_expression_every = 1;
  // Throws InvalidOptions.
  void Validate() const;
};

class DetailFrameSource : public FrameSource {
 public:
  // `base` renders the head; `analysis` is the portrait's (its fit, aligned photo, matte and
  // eye/mouth mask); its morphable model must outlive the source. Throws InvalidInput.
  // With mode "head" the base's depth at the source view is rendered once here: a base without
  // depth, or with nothing opaque there, keeps the face mesh only and says so in Warnings().
  DetailFrameSource(std::shared_ptr<const FrameSource> base, const SourceAnalysis& analysis,
                    const DetailOptions& options = {});

  std::string Label() const override;
  bool SupportsPose() const override { return base_->SupportsPose(); }
  std::vector<std::string> ExpressionControls() const override { return base_->ExpressionControls(); }
  int CoefficientCount() const override { return base_->CoefficientCount(); }
  ViewPose SourcePose() const override { return base_->SourcePose(); }
  SourceOverlay Overlay() const override { return base_->Overlay(); }
  RenderedFrame Render(const FrameRequest& request, RunContext& ctx) const override;
  // The detail frame of `request` composed over the last base frame rendered for the same view
  // and size (by Render or RenderLayers, at any expression): the photo's face follows the new
  // expression at once, without calling the base source (the network). The eyes' and mouth's
  // openings keep the kept frame's network pixels (the mouth's interior is painted as always)
  // until the full frame follows; no fusion net. Frames larger than kQuickSide are composed at
  // that side and upscaled (a 512 px viewport gets a 256 px quick frame). nullopt when no base
  // frame of that view and size is kept. stages = "face update".
  std::optional<RenderedFrame> RenderQuick(const FrameRequest& request, RunContext& ctx) const override;
  // Frames that called the base source, and quick frames composed over a kept one.
  struct Counts {
    int64_t base_renders = 0, quick = 0;
  };
  Counts counts() const;
  static constexpr int kQuickSide = 256;
  // The geometric composite and the layers it was composed from (Render's frame without the
  // fusion net; with it, Render finishes this frame).
  DetailLayers RenderLayers(const FrameRequest& request, RunContext& ctx) const;
  bool HasFusion() const { return fusion_ != nullptr; }

  // The face mesh's warp of one request alone (for tests and measurements).
  compose::FaceWarp Warp(const FrameRequest& request) const;
  // The depth warp of a rendered base frame of `request` (all invalid without the depth proxy).
  // `face` is the face mesh's coverage of the request (FaceWarp::face; empty = rasterised here).
  compose::FaceWarp DepthWarp(const FrameRequest& request, const RenderedFrame& base_frame,
                              const cv::Mat& face = cv::Mat()) const;
  // What align_depth_to_face added to the network's depth (0 when off, without the head proxy, or
  // when the mesh and the network share too few pixels at the photo's view).
  double depth_offset() const { return depth_offset_; }
  bool HasDepthProxy() const { return depth_ != nullptr; }

  // The studio's OpenGL viewport (issue 34): this source's portrait as textured meshes (the face
  // mesh with the fit's texture and the head's height field with the photo: BuildHeadMesh of
  // head_mesh.h over the base source), and behind them the base source's own frames at the
  // photo's view and turned 30 degrees each way (NetworkViewMesh, parts named "network ..."), so
  // that a camera move is a redraw, not a render. Costs four base renders (192 and 3 x 128 px);
  // the caller keeps the result. Throws Cancelled, InvalidInput.
  std::shared_ptr<const HeadMesh> ViewportMesh(RunContext& ctx) const;
  // What the viewport draws those meshes with for `request`: its camera (the detail path's own,
  // CameraForView of the request's view) and the face part's vertices at the request's
  // expression (a blend of the morphable bases: microseconds).
  struct MeshView {
    CameraLabel25 camera{};
    std::vector<cv::Point3f> face;
  };
  MeshView ViewportView(const FrameRequest& request) const;
  // Live driving's form of this source (LiveFrameSource, live.h): the same detail path over the
  // same base with the network taking a new expression on every `every`th frame
  // (DetailOptions::base_expression_every) and, unless `keep_fusion`, without the fusion net:
  // live frames are the geometric composite by default, since the net's ~30 ms per 256 px frame
  // on 2 cores would take live under its 15 fps (docs/PERFORMANCE.md). Renders the source view's
  // depth again (one base render). Throws InvalidOptions.
  std::shared_ptr<const DetailFrameSource> ForLive(int every, bool keep_fusion = false) const;
  // The same detail path over the same base finished by the fusion net of `weights` ("" = none:
  // the geometric composite; the studio's "Learned finish" switch). Renders the source view's
  // depth again (one base render). Throws Io / ModelLoad for weights that do not load.
  std::shared_ptr<const DetailFrameSource> WithFusion(const std::string& weights) const;
  // The detail source `source` is or wraps (through FrameSource::Wrapped), or null.
  static const DetailFrameSource* Find(const FrameSource* source);
  const FrameSource& base() const { return *base_; }
  std::shared_ptr<const FrameSource> Wrapped() const override { return base_; }

 private:
  std::shared_ptr<const FrameSource> base_;
  std::shared_ptr<const SourceAnalysis> analysis_;  // the portrait's (ViewportMesh)
  const morphable::MorphableModel* model_;
  compose::EdgeMatte photo_;  // the photo and matte both warps read (clean_edges)
  compose::FaceDetail detail_;
  DetailOptions options_;
  std::unique_ptr<compose::DepthDetail> depth_;
  double depth_offset_ = 0.0;  // align_depth_to_face: added to the network's depth (world units)
  struct Fusion;
  std::shared_ptr<Fusion> fusion_;     // the learned finish (options.fusion)
  // The layers of `request` over `base_frame` (the base source's frame of the same view).
  DetailLayers Compose(const FrameRequest& request, RenderedFrame base_frame, RunContext& ctx) const;
  // The last base frame and the view and size it was rendered for (RenderQuick).
  struct Kept;
  std::shared_ptr<Kept> kept_;
};

// The start of the label suffix of every frame with the detail path; DetailLabel(mode) is the
// whole suffix (" + the photo's detail on the head" / "... on the face").
inline constexpr const char* kDetailLabel = " + the photo's detail";
std::string DetailLabel(const std::string& mode);

}  // namespace avatar
