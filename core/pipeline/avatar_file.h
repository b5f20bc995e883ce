#pragma once
// The .avatar file format (a TensorArchive of kind "goha-avatar", core/model/checkpoint.h):
//   meta:    config (the model config JSON), model_id, camera (25 floats, C_s),
//            expression_kind (ExpressionImageSource::Kind(), "" for none), refinement (optional JSON)
//   tensors: avatar.canonical, avatar.appearance  [1,3,C,P,P] float32 (T_c, T_p)
//            avatar.source_image                  [512,512,3] uint8 (BGR aligned portrait)
//            avatar.expression_source             [N] uint8 (ExpressionImageSource::Serialize())
//   optional, the portrait's analysis for the photo's detail path (AvatarPortrait; written since
//   2026-12-05, older files load without it and render without the detail path):
//   meta:    portrait_fit {alpha, beta, scale, camera (25), image_size [w, h]}
//   tensors: portrait.unmatted [S,S,3] uint8 (BGR crop), portrait.matte [S,S] float32,
//            portrait.eye_mouth [S,S] uint8, portrait.landmarks [N,3] float32
// The expression source is rebuilt by the loader registered for its kind
// (RegisterExpressionSourceLoader, session.h). Internal to core/pipeline: callers use
// Session::SaveAvatar / LoadAvatar and ReadAvatarFileInfo.

#include <filesystem>
#include <memory>
#include <string>

#include "core/model/goha_model.h"
#include "core/pipeline/avatar_state.h"

namespace avatar {

// Writes `state` atomically. Throws Io.
void WriteAvatarFile(const AvatarState& state, const std::filesystem::path& path);
// Reads an avatar made with exactly `config` and `model_id` (a new process-wide id, base planes
// summed). Throws Io (missing), ModelLoad naming the file (not an avatar, damaged, other model
// or config, unknown expression source kind).
std::shared_ptr<AvatarState> ReadAvatarFile(const std::filesystem::path& path, const ModelConfig& config,
                                            const std::string& model_id);

}  // namespace avatar
