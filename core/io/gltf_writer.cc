#include "core/io/gltf_writer.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "core/io/atomic_file.h"
#include "core/util/error.h"

namespace avatar {
namespace {

// glTF constants.
constexpr int kFloat = 5126;
constexpr int kUnsignedInt = 5125;
constexpr int kArrayBuffer = 34962;
constexpr int kElementArrayBuffer = 34963;
constexpr int kLinear = 9729;
constexpr int kClampToEdge = 33071;

void AppendPadded(std::string* bin, const void* data, size_t bytes) {
  bin->append(static_cast<const char*>(data), bytes);
  while (bin->size() % 4 != 0) bin->push_back('\0');
}

void PutU32(std::string* out, uint32_t v) {
  for (int i = 0; i < 4; ++i) out->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}

std::string PngOf(const cv::Mat& texture, const std::string& name) {
  std::vector<uchar> png;
  AVATAR_CHECK_INPUT(cv::imencode(".png", texture, png)) << "mesh part '" << name << "': its texture does not encode";
  return std::string(png.begin(), png.end());
}

}  // namespace

void TexturedMesh::Validate() const {
  AVATAR_CHECK_INPUT(!positions.empty() && !triangles.empty()) << "mesh part '" << name << "' is empty";
  AVATAR_CHECK_INPUT(uv.size() == positions.size())
      << "mesh part '" << name << "': " << uv.size() << " UVs for " << positions.size() << " positions";
  AVATAR_CHECK_INPUT(!texture.empty() && texture.depth() == CV_8U && (texture.channels() == 3 || texture.channels() == 4))
      << "mesh part '" << name << "': the texture must be an 8-bit BGR or BGRA image";
  for (const cv::Point3f& p : positions)
    AVATAR_CHECK_INPUT(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z))
        << "mesh part '" << name << "' has a non-finite position";
  for (const cv::Point2f& t : uv)
    AVATAR_CHECK_INPUT(std::isfinite(t.x) && std::isfinite(t.y)) << "mesh part '" << name << "' has a non-finite UV";
  const int n = static_cast<int>(positions.size());
  for (const cv::Vec3i& f : triangles)
    for (int k = 0; k < 3; ++k)
      AVATAR_CHECK_INPUT(f[k] >= 0 && f[k] < n) << "mesh part '" << name << "': vertex index " << f[k] << " out of range";
}

std::string EncodeGlb(const std::vector<TexturedMesh>& meshes, const std::string& generator) {
  AVATAR_CHECK_INPUT(!meshes.empty()) << "no mesh to write";
  nlohmann::json j;
  j["asset"] = {{"version", "2.0"}, {"generator", generator}};
  j["extensionsUsed"] = {"KHR_materials_unlit"};
  j["scene"] = 0;
  j["samplers"] = {{{"magFilter", kLinear}, {"minFilter", kLinear}, {"wrapS", kClampToEdge}, {"wrapT", kClampToEdge}}};
  nlohmann::json nodes = nlohmann::json::array(), scene_nodes = nlohmann::json::array();
  nlohmann::json out_meshes = nlohmann::json::array(), materials = nlohmann::json::array();
  nlohmann::json textures = nlohmann::json::array(), images = nlohmann::json::array();
  nlohmann::json accessors = nlohmann::json::array(), views = nlohmann::json::array();
  std::string bin;
  auto add_view = [&](const void* data, size_t bytes, int target) {
    nlohmann::json v = {{"buffer", 0}, {"byteOffset", bin.size()}, {"byteLength", bytes}};
    if (target != 0) v["target"] = target;
    AppendPadded(&bin, data, bytes);
    views.push_back(v);
    return static_cast<int>(views.size()) - 1;
  };
  for (const TexturedMesh& m : meshes) {
    m.Validate();
    const int i = static_cast<int>(out_meshes.size());
    // Positions with their bounds (required by glTF for POSITION).
    std::vector<float> pos;
    pos.reserve(3 * m.positions.size());
    float lo[3] = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
                   std::numeric_limits<float>::max()};
    float hi[3] = {-lo[0], -lo[1], -lo[2]};
    for (const cv::Point3f& p : m.positions) {
      const float v[3] = {p.x, p.y, p.z};
      for (int k = 0; k < 3; ++k) {
        pos.push_back(v[k]);
        lo[k] = std::min(lo[k], v[k]);
        hi[k] = std::max(hi[k], v[k]);
      }
    }
    std::vector<float> uv;
    uv.reserve(2 * m.uv.size());
    for (const cv::Point2f& t : m.uv) {
      uv.push_back(t.x);
      uv.push_back(t.y);
    }
    std::vector<uint32_t> idx;
    idx.reserve(3 * m.triangles.size());
    for (const cv::Vec3i& f : m.triangles)
      for (int k = 0; k < 3; ++k) idx.push_back(static_cast<uint32_t>(f[k]));
    const int vp = add_view(pos.data(), pos.size() * sizeof(float), kArrayBuffer);
    accessors.push_back({{"bufferView", vp},
                         {"componentType", kFloat},
                         {"count", m.positions.size()},
                         {"type", "VEC3"},
                         {"min", {lo[0], lo[1], lo[2]}},
                         {"max", {hi[0], hi[1], hi[2]}}});
    const int a_pos = static_cast<int>(accessors.size()) - 1;
    const int vt = add_view(uv.data(), uv.size() * sizeof(float), kArrayBuffer);
    accessors.push_back({{"bufferView", vt}, {"componentType", kFloat}, {"count", m.uv.size()}, {"type", "VEC2"}});
    const int a_uv = static_cast<int>(accessors.size()) - 1;
    const int vi = add_view(idx.data(), idx.size() * sizeof(uint32_t), kElementArrayBuffer);
    accessors.push_back({{"bufferView", vi}, {"componentType", kUnsignedInt}, {"count", idx.size()}, {"type", "SCALAR"}});
    const int a_idx = static_cast<int>(accessors.size()) - 1;
    const std::string png = PngOf(m.texture, m.name);
    const int vimg = add_view(png.data(), png.size(), 0);
    images.push_back({{"bufferView", vimg}, {"mimeType", "image/png"}, {"name", m.name}});
    textures.push_back({{"sampler", 0}, {"source", i}});
    materials.push_back({{"name", m.name},
                         {"doubleSided", true},
                         {"pbrMetallicRoughness",
                          {{"baseColorTexture", {{"index", i}}}, {"metallicFactor", 0.0}, {"roughnessFactor", 1.0}}},
                         {"extensions", {{"KHR_materials_unlit", nlohmann::json::object()}}}});
    out_meshes.push_back(
        {{"name", m.name},
         {"primitives",
          {{{"attributes", {{"POSITION", a_pos}, {"TEXCOORD_0", a_uv}}}, {"indices", a_idx}, {"material", i}}}}});
    nodes.push_back({{"name", m.name}, {"mesh", i}});
    scene_nodes.push_back(i);
  }
  j["scenes"] = {{{"nodes", scene_nodes}}};
  j["nodes"] = nodes;
  j["meshes"] = out_meshes;
  j["materials"] = materials;
  j["textures"] = textures;
  j["images"] = images;
  j["accessors"] = accessors;
  j["bufferViews"] = views;
  j["buffers"] = {{{"byteLength", bin.size()}}};
  std::string json = j.dump();
  while (json.size() % 4 != 0) json.push_back(' ');
  std::string out;
  out.reserve(12 + 8 + json.size() + 8 + bin.size());
  PutU32(&out, 0x46546C67u);  // "glTF"
  PutU32(&out, 2u);
  PutU32(&out, static_cast<uint32_t>(12 + 8 + json.size() + 8 + bin.size()));
  PutU32(&out, static_cast<uint32_t>(json.size()));
  PutU32(&out, 0x4E4F534Au);  // "JSON"
  out += json;
  PutU32(&out, static_cast<uint32_t>(bin.size()));
  PutU32(&out, 0x004E4942u);  // "BIN\0"
  out += bin;
  return out;
}

void WriteMeshFile(const std::filesystem::path& path, const std::vector<TexturedMesh>& meshes,
                   const std::string& generator) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  AVATAR_CHECK_OPTION(ext == ".glb" || ext == ".obj")
      << "'" << path.string() << "': the mesh file must end in .glb (binary glTF) or .obj";
  if (ext == ".glb") {
    WriteBytesAtomically(path, EncodeGlb(meshes, generator));
    return;
  }
  AVATAR_CHECK_INPUT(!meshes.empty()) << "no mesh to write";
  // OBJ: one group per part, its material's PNG beside the file. OBJ's v runs upwards.
  const std::string stem = path.stem().string();
  std::ostringstream obj, mtl;
  obj << "# " << generator << "\nmtllib " << stem << ".mtl\n";
  int base = 1;
  for (size_t i = 0; i < meshes.size(); ++i) {
    const TexturedMesh& m = meshes[i];
    m.Validate();
    const std::string png_name = stem + "_" + m.name + ".png";
    WriteBytesAtomically(path.parent_path() / png_name, PngOf(m.texture, m.name));
    mtl << "newmtl " << m.name << "\nKa 1 1 1\nKd 1 1 1\nillum 0\nmap_Kd " << png_name << "\n";
    obj << "o " << m.name << "\nusemtl " << m.name << "\n";
    for (const cv::Point3f& p : m.positions) obj << "v " << p.x << " " << p.y << " " << p.z << "\n";
    for (const cv::Point2f& t : m.uv) obj << "vt " << t.x << " " << 1.0f - t.y << "\n";
    for (const cv::Vec3i& f : m.triangles) {
      obj << "f";
      for (int k = 0; k < 3; ++k) obj << " " << base + f[k] << "/" << base + f[k];
      obj << "\n";
    }
    base += static_cast<int>(m.positions.size());
  }
  std::filesystem::path mtl_path = path;
  mtl_path.replace_extension(".mtl");
  WriteBytesAtomically(mtl_path, mtl.str());
  WriteBytesAtomically(path, obj.str());
}

}  // namespace avatar
