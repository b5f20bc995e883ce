#pragma once
// Binary glTF 2.0 (.glb) and Wavefront OBJ output of textured triangle meshes: one node and one
// mesh per part, each with its own embedded PNG texture and an unlit material
// (KHR_materials_unlit: the texture is a photo, already lit). Coordinates are glTF's: metres are
// not implied, +Y up, the front of a head towards +Z.

#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace avatar {

struct TexturedMesh {
  std::string name;
  std::vector<cv::Point3f> positions;
  std::vector<cv::Point2f> uv;       // per position, in [0,1], origin at the texture's top-left
  std::vector<cv::Vec3i> triangles;  // counter-clockwise seen from the front
  cv::Mat texture;                   // CV_8UC3 BGR or CV_8UC4 BGRA

  // Throws InvalidInput naming the part: uv count, indices out of range, non-finite values,
  // empty texture.
  void Validate() const;
};

// The bytes of a .glb holding `meshes` (at least one, each with at least one triangle).
std::string EncodeGlb(const std::vector<TexturedMesh>& meshes, const std::string& generator);

// Writes `meshes` to `path` atomically: .glb (EncodeGlb) or .obj (with a .mtl and one PNG per
// part beside it, named after the file). Throws InvalidOptions for another extension,
// InvalidInput for bad meshes, Io.
void WriteMeshFile(const std::filesystem::path& path, const std::vector<TexturedMesh>& meshes,
                   const std::string& generator);

}  // namespace avatar
