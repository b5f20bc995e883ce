#pragma once
// The MediaPipe canonical face mesh: 468 vertices with UVs and 898 triangles, read from the
// installed @mediapipe/face_mesh asset bundle by our own loader (the bundle is a concatenation
// of files whose offsets the accompanying loader .js lists; the mesh is a small protobuf).

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "core/io/data_paths.h"

namespace avatar::morphable {

// Vertices of the topology (same order as the facemesh landmarks).
inline constexpr int kVertexCount = 468;

struct Topology {
  // Canonical vertex positions in centimetres: x to the face's left (image right in a frontal
  // view), y up, z towards the viewer (the nose tip has the largest z).
  std::vector<cv::Point3f> canonical_cm;
  // Texture coordinates in [0,1]^2 with v growing downwards (image convention).
  std::vector<cv::Point2f> uv;
  // Triangles as vertex indices, counter-clockwise seen from the front (+z).
  std::vector<cv::Vec3i> triangles;
  // MediaPipe's Procrustes landmark weights: (vertex index, weight) of the rigid points.
  std::vector<std::pair<int, float>> procrustes;
  // mirror[i]: the vertex symmetric to i about the x = 0 plane.
  std::vector<int> mirror;
};

// Relative path of the asset bundle under the data folder.
inline constexpr const char* kMeshAssetData = "mediapipe/face_mesh_solution_packed_assets.data";
inline constexpr const char* kMeshAssetLoader = "mediapipe/face_mesh_solution_packed_assets_loader.js";

// Extracts one file of a packed asset bundle using the offsets in its loader script.
// Throws Io (unreadable files) or ModelLoad (file not listed, offsets outside the bundle).
std::string ReadPackedAsset(const std::filesystem::path& data_file, const std::filesystem::path& loader_js,
                            const std::string& name_suffix);

// Decodes the geometry pipeline metadata protobuf. Throws ModelLoad naming `source` when the
// bytes are not a 468-vertex mesh with valid triangles.
Topology ParseTopology(const std::string& protobuf_bytes, const std::string& source);

// Reads the canonical mesh from the installed data (MissingData if setup has not run). The
// result is cached per process.
const Topology& LoadTopology(const DataPaths& paths);

// Orients every triangle counter-clockwise seen from +z and fills `mirror` (exposed for tests).
void FinishTopology(Topology& topology);

}  // namespace avatar::morphable
