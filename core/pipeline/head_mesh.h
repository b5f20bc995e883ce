#pragma once
// The avatar as textured meshes for other programs (`avatar-studio export-mesh`): the geometry
// proxy of the detail path with the photo's pixels on it.
//  - "face": the fitted morphable face mesh at the portrait's expression, with the fit's UV
//    texture (the photo where it saw the face, inpainted elsewhere);
//  - "head": hair, ears, neck and shoulders as a height field of the network's depth at the
//    photo's view (the same 2.5D proxy the detail path warps through), over the person's pixels
//    the face mesh does not cover, textured with the photo itself. It is torn at depth jumps
//    (silhouettes) and has nothing behind what the photo saw.

#include <memory>
#include <string>
#include <vector>

#include "core/io/gltf_writer.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/session.h"
#include "core/pipeline/source_analysis.h"
#include "core/util/run_context.h"

namespace avatar {

struct HeadMeshOptions {
  // Side of the network's source-view depth map the height field is built on (one vertex per
  // pixel).
  int depth_size = 192;
  // Gaussian smoothing of that depth (fraction of its height): the bundled model renders at 32 px.
  double depth_smoothing = 0.02;
  // Largest depth step between neighbouring vertices of one triangle, as a fraction of the
  // camera distance (2.7); larger steps are silhouettes and stay open.
  double max_depth_step = 0.03;
  // Matte value below which a photo pixel is background (no height field there).
  float min_matte = 0.5f;
  // Whether the height field covers the photo's whole person (the depth filled beyond the
  // network's silhouette, as the detail path's proxy does: compose::DepthDetailOptions) or only
  // where the network is opaque.
  bool extend_to_matte = true;
  // Side of the face part's UV texture (the fit's texture is resampled to it).
  int face_texture_size = 512;
  // Whether the height field continues under the face mesh (the studio's viewport draws it behind
  // the face, so that a turned face that moves off it shows the photo, not a slit; an exported
  // file keeps the two parts apart).
  bool under_face = false;
  // The height field's depth moved onto the fitted face mesh as the detail path moves its proxy
  // (DetailOptions::align_depth_to_face, off by default there too; compose::FaceDepthOffset).
  bool align_depth_to_face = false;
  double align_depth_reach = 0.1;  // DetailOptions::align_depth_reach

  template <typename V>
  void Visit(V&& v) {
    v("depth_size", depth_size, "Side of the source-view depth the head's height field is built on");
    v("max_depth_step", max_depth_step, "Largest depth step inside a triangle (fraction of the camera distance)");
    v("extend_to_matte", extend_to_matte, "Cover the photo's whole person, not only the network's opaque pixels");
    v("face_texture_size", face_texture_size, "Side of the face's UV texture");
    v("under_face", under_face, "Continue the head's height field under the face mesh");
    v("align_depth_to_face", align_depth_to_face, "Move the head's depth onto the fitted face mesh");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

struct HeadMesh {
  std::vector<TexturedMesh> parts;    // "face" and, when the network renders the head, "head"
  std::vector<std::string> warnings;  // what the user should know (e.g. the face alone)
};

// The meshes of a portrait's analysis and the network that renders it (`network` gives the
// source-view depth; a source without depth, or with nothing opaque there, yields the face
// alone with a warning). World coordinates of the renderer: +Y up, the face towards +Z, the
// camera 2.7 from the origin. Throws InvalidInput, Cancelled.
HeadMesh BuildHeadMesh(const SourceAnalysis& analysis, const FrameSource& network, const HeadMeshOptions& options,
                       RunContext& ctx);

// The network's own frame at `view` (RGB and depth at `size` px, CameraForView of the view and
// `source_camera`) as a height field textured with that frame, over its opaque pixels and closed
// across depth steps up to `max_depth_step` of the camera distance: what the studio's viewport
// draws behind the photo's parts, where the photo did not see (the far side of a turned head).
// Named "network" plus the view's yaw. Empty (no triangles) when nothing is opaque there.
TexturedMesh NetworkViewMesh(const FrameSource& network, const ViewPose& view, const CameraLabel25& source_camera,
                             int size, double max_depth_step, RunContext& ctx);

// The same for a saved avatar (Session::LoadAvatar) that keeps its portrait's analysis; one saved
// before that throws InvalidInput saying to reconstruct the portrait again.
HeadMesh AvatarHeadMesh(std::shared_ptr<const Session> session, const Avatar& avatar, const std::string& data_dir,
                        const HeadMeshOptions& options, RunContext& ctx);

}  // namespace avatar
