#pragma once
// Files that ship with the application itself (the morphable face model, the bundled neural
// model), as opposed to the data that scripts/setup downloads (core/io/data_paths.h).
//
// A resource `relative` (e.g. "models/goha-default.ckpt") is looked up:
//   - when $AVATAR_RESOURCE_DIR is set, in $AVATAR_RESOURCE_DIR/relative only (relocated
//     installs, and tests that need a resource to be missing);
//   - otherwise in <prefix>/share/avatar-studio/relative, where <prefix> is the folder above the
//     running executable's bin/ (an installed package, wherever it was installed), then in
//     <source tree>/resources/relative (a build tree).
// The first that exists wins; when none does, the last candidate is returned so that the error
// a caller raises names a real place.

#include <filesystem>
#include <string>
#include <vector>

namespace avatar {

// The bundled neural model (float16 weights), relative to the resource folder.
inline constexpr const char* kBundledModelFile = "models/goha-default.ckpt";
// The bundled fusion net that finishes the detail path's frames of the bundled model (float16;
// core/model/fusion_net.h, docs/MODEL.md).
inline constexpr const char* kBundledFusionFile = "models/fusion-default.ckpt";

// See the header comment.
std::filesystem::path ResourcePath(const std::string& relative);
// Every place ResourcePath looks, in order (for error messages).
std::vector<std::filesystem::path> ResourceCandidates(const std::string& relative);
// <prefix>/share/avatar-studio of the running executable (the folder above its bin/), or an
// empty path when /proc/self/exe cannot be read. An installed package keeps its data there too
// (core/io/data_paths.h).
std::filesystem::path InstalledDataDir();

}  // namespace avatar
