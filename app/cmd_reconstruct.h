#pragma once
// `avatar-studio reconstruct IMAGE -o FILE.avatar`: face analysis, morphable fit and the GOHA
// reconstruction (T_c, T_p), saved as an avatar file for `render` and the studio.
// `avatar-studio render FILE.avatar [--yaw --pitch --roll] [--expr name=value ...] [--mode]
// -o out.png [--alpha] [--depth]`: one frame of an avatar.
// `avatar-studio export-mesh FILE.avatar -o head.glb|head.obj`: the avatar's geometry proxy with
// the photo on it, for other programs (core/pipeline/head_mesh.h).

#include <string>
#include <vector>

#include "app/commands.h"
#include "core/pipeline/head_mesh.h"
#include "core/pipeline/reconstruct.h"
#include "core/pipeline/session.h"
#include "core/pipeline/studio_backend.h"

namespace avatar::app {

struct ReconstructOptions {
  // Portrait photo.
  std::string input;
  // Avatar file to write.
  std::string output = "portrait.avatar";
  // Model selection.
  SessionOptions session;
  // Quality level (core/pipeline/quality.h: instant ... best, paper); "" = none. Its refinement
  // applies unless --refine-steps or --refine-seconds is given.
  std::string quality;
  // Optional per-portrait refinement of the planes (--refine-steps, --refine-seconds, ...).
  RefineOptions refine = ReconstructionOptions::NoRefinement();
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("output", output, "Avatar file to write (.avatar)", 'o');
    v("quality", quality,
      "Quality level: instant, preview, standard, fine, best or paper (the published setting); see the list below");
    refine.Visit(v);
    session.Visit(v);
    common.Visit(v);
  }
  void Validate() const;
};

int RunReconstruct(const std::vector<std::string>& args);
int RunReconstructImpl(const ReconstructOptions& options, RunContext& ctx);

struct RenderCommandOptions {
  // Avatar file to render.
  std::string input;
  // Output image (.png; .jpg without --alpha).
  std::string output = "avatar.png";
  // Camera yaw in degrees.
  double yaw = 0.0;
  // Camera pitch in degrees (-90..90 exclusive).
  double pitch = 0.0;
  // Camera roll in degrees.
  double roll = 0.0;
  // Expression controls, name=value (repeatable).
  std::vector<std::string> expr;
  // Render mode: preview, standard or final.
  std::string mode = "final";
  // Write RGBA with the rendered opacity as alpha.
  bool alpha = false;
  // Also write the depth map as a 16-bit PNG next to the output (<name>_depth.png).
  bool depth = false;
  // The photo's detail over the network render (head, geometric, face or off; BackendOptions::detail) and
  // the fusion net that finishes it. Needs an avatar that keeps its portrait's analysis.
  std::string detail = "head";
  std::string fusion;
  // Side of the output image with the detail path (the network alone renders at its mode's size).
  int size = 512;
  // Model selection.
  SessionOptions session;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("output", output, "Output image", 'o');
    v("yaw", yaw, "Camera yaw in degrees (positive: camera moves to the subject's left)");
    v("pitch", pitch, "Camera pitch in degrees (positive: camera above)");
    v("roll", roll, "Camera roll in degrees");
    v("expr", expr, "Expression control name=value (repeatable), e.g. --expr jawOpen=0.5");
    v("mode", mode, "Render mode: preview (fast, small), standard (render size) or final (with super-resolution)");
    v("alpha", alpha, "Write RGBA with the rendered opacity as alpha");
    v("depth", depth, "Also write <output>_depth.png (16-bit, near 2.25 = 0, far 3.3 = 65535)");
    v("detail", detail,
      "The photo's detail over the network render: head (finished by the learned fusion net), geometric (the same "
      "without the net), face or off (avatars saved since 2026-12-05 keep what it needs)");
    v("fusion", fusion,
      "Fusion net weights that finish the detail frame (\"\" = the bundled net with --detail head, none otherwise)");
    v("size", size, "Output side with the detail path, in pixels");
    session.Visit(v);
    common.Visit(v);
  }
  void Validate() const;
  // The detail path's options for SavedAvatarSource.
  BackendOptions Backend() const;
};

int RunRender(const std::vector<std::string>& args);
int RunRenderImpl(const RenderCommandOptions& options, RunContext& ctx);

struct ExportMeshOptions {
  // Avatar file to export.
  std::string input;
  // Mesh file to write: .glb (binary glTF 2.0, textures inside) or .obj (+ .mtl and PNGs beside it).
  std::string output = "head.glb";
  HeadMeshOptions mesh;
  // Model selection (the network whose depth shapes hair, ears and neck).
  SessionOptions session;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("output", output, "Mesh file to write: .glb (binary glTF) or .obj", 'o');
    mesh.Visit(v);
    session.Visit(v);
    common.Visit(v);
  }
  void Validate() const;
};

int RunExportMesh(const std::vector<std::string>& args);
int RunExportMeshImpl(const ExportMeshOptions& options, RunContext& ctx);

}  // namespace avatar::app
