#include "core/morphable/topology.h"

#include <cmath>
#include <cstring>
#include <map>
#include <mutex>
#include <regex>

#include "core/io/atomic_file.h"
#include "core/util/error.h"

namespace avatar::morphable {

namespace {

// Minimal protobuf wire-format reader (varints, fixed32, length-delimited).
class WireReader {
 public:
  WireReader(const char* data, size_t size, const std::string& source) : p_(data), end_(data + size), src_(source) {}
  bool Done() const { return p_ >= end_; }
  uint64_t Varint() {
    uint64_t v = 0;
    for (int shift = 0; shift < 64; shift += 7) {
      AVATAR_CHECK_AS(ModelLoad, p_ < end_) << src_ << ": truncated protobuf varint; re-run scripts/setup";
      const auto b = static_cast<uint8_t>(*p_++);
      v |= static_cast<uint64_t>(b & 0x7f) << shift;
      if ((b & 0x80) == 0) return v;
    }
    throw ModelLoad(src_ + ": malformed protobuf varint; re-run scripts/setup");
  }
  float Fixed32() {
    AVATAR_CHECK_AS(ModelLoad, end_ - p_ >= 4) << src_ << ": truncated protobuf float; re-run scripts/setup";
    float f;
    std::memcpy(&f, p_, 4);
    p_ += 4;
    return f;
  }
  WireReader Sub() {
    const uint64_t n = Varint();
    AVATAR_CHECK_AS(ModelLoad, n <= static_cast<uint64_t>(end_ - p_))
        << src_ << ": protobuf field runs past the end; re-run scripts/setup";
    WireReader r(p_, n, src_);
    p_ += n;
    return r;
  }
  void Skip(int wire_type) {
    switch (wire_type) {
      case 0:
        Varint();
        break;
      case 1:
        Advance(8);
        break;
      case 2:
        Sub();
        break;
      case 5:
        Advance(4);
        break;
      default:
        throw ModelLoad(src_ + ": unsupported protobuf wire type; re-run scripts/setup");
    }
  }

 private:
  void Advance(size_t n) {
    AVATAR_CHECK_AS(ModelLoad, static_cast<size_t>(end_ - p_) >= n) << src_ << ": truncated protobuf";
    p_ += n;
  }
  const char* p_;
  const char* end_;
  std::string src_;
};

void ReadFloats(WireReader& r, int wire_type, std::vector<float>& out) {
  if (wire_type == 5) {
    out.push_back(r.Fixed32());
  } else if (wire_type == 2) {
    WireReader packed = r.Sub();
    while (!packed.Done()) out.push_back(packed.Fixed32());
  } else {
    r.Skip(wire_type);
  }
}

void ReadUints(WireReader& r, int wire_type, std::vector<uint32_t>& out) {
  if (wire_type == 0) {
    out.push_back(static_cast<uint32_t>(r.Varint()));
  } else if (wire_type == 2) {
    WireReader packed = r.Sub();
    while (!packed.Done()) out.push_back(static_cast<uint32_t>(packed.Varint()));
  } else {
    r.Skip(wire_type);
  }
}

}  // namespace

std::string ReadPackedAsset(const std::filesystem::path& data_file, const std::filesystem::path& loader_js,
                            const std::string& name_suffix) {
  const std::string loader = ReadFileBytes(loader_js);
  // Entries look like {"filename": "/.../name", "start": 123, "end": 456, ...}.
  const std::regex entry(R"re("filename"\s*:\s*"([^"]*)"\s*,\s*"start"\s*:\s*(\d+)\s*,\s*"end"\s*:\s*(\d+))re");
  for (auto it = std::sregex_iterator(loader.begin(), loader.end(), entry); it != std::sregex_iterator(); ++it) {
    const std::string name = (*it)[1];
    if (name.size() < name_suffix.size() ||
        name.compare(name.size() - name_suffix.size(), name_suffix.size(), name_suffix) != 0) {
      continue;
    }
    const uint64_t start = std::stoull((*it)[2]);
    const uint64_t end = std::stoull((*it)[3]);
    const std::string data = ReadFileBytes(data_file);
    AVATAR_CHECK_AS(ModelLoad, start < end && end <= data.size())
        << data_file.string() << ": offsets of " << name << " lie outside the bundle; re-run scripts/setup";
    return data.substr(start, end - start);
  }
  throw ModelLoad(loader_js.string() + " does not list '" + name_suffix + "'; re-run scripts/setup");
}

Topology ParseTopology(const std::string& bytes, const std::string& source) {
  std::vector<float> vertex_buffer;
  std::vector<uint32_t> index_buffer;
  Topology topo;
  WireReader top(bytes.data(), bytes.size(), source);
  while (!top.Done()) {
    const uint64_t key = top.Varint();
    const int field = static_cast<int>(key >> 3);
    const int wire = static_cast<int>(key & 7);
    if (field == 1 && wire == 2) {  // canonical_mesh (Mesh3d)
      WireReader mesh = top.Sub();
      while (!mesh.Done()) {
        const uint64_t k = mesh.Varint();
        const int f = static_cast<int>(k >> 3);
        const int w = static_cast<int>(k & 7);
        if (f == 1 || f == 2) {
          const uint64_t v = mesh.Varint();
          AVATAR_CHECK_AS(ModelLoad, v == 0) << source << ": unexpected mesh vertex/primitive type " << v;
        } else if (f == 3) {
          ReadFloats(mesh, w, vertex_buffer);
        } else if (f == 4) {
          ReadUints(mesh, w, index_buffer);
        } else {
          mesh.Skip(w);
        }
      }
    } else if (field == 2 && wire == 2) {  // procrustes_landmark_basis (WeightedLandmarkRef)
      WireReader ref = top.Sub();
      int id = -1;
      float weight = 0.0f;
      while (!ref.Done()) {
        const uint64_t k = ref.Varint();
        const int f = static_cast<int>(k >> 3);
        const int w = static_cast<int>(k & 7);
        if (f == 1 && w == 0) {
          id = static_cast<int>(ref.Varint());
        } else if (f == 2 && w == 5) {
          weight = ref.Fixed32();
        } else {
          ref.Skip(w);
        }
      }
      AVATAR_CHECK_AS(ModelLoad, id >= 0 && id < kVertexCount) << source << ": Procrustes landmark id out of range";
      topo.procrustes.emplace_back(id, weight);
    } else {
      top.Skip(wire);
    }
  }
  AVATAR_CHECK_AS(ModelLoad, vertex_buffer.size() == static_cast<size_t>(kVertexCount) * 5)
      << source << ": expected " << kVertexCount << " vertices of (x,y,z,u,v), got " << vertex_buffer.size()
      << " floats; re-run scripts/setup";
  AVATAR_CHECK_AS(ModelLoad, !index_buffer.empty() && index_buffer.size() % 3 == 0)
      << source << ": triangle index buffer has " << index_buffer.size() << " entries";
  for (int i = 0; i < kVertexCount; ++i) {
    const float* v = &vertex_buffer[static_cast<size_t>(i) * 5];
    for (int c = 0; c < 5; ++c) {
      AVATAR_CHECK_AS(ModelLoad, std::isfinite(v[c])) << source << ": non-finite vertex data";
    }
    topo.canonical_cm.emplace_back(v[0], v[1], v[2]);
    // The asset's v already grows downwards (forehead ~0.1, chin ~0.95).
    topo.uv.emplace_back(v[3], v[4]);
  }
  for (size_t t = 0; t < index_buffer.size(); t += 3) {
    cv::Vec3i tri(static_cast<int>(index_buffer[t]), static_cast<int>(index_buffer[t + 1]),
                  static_cast<int>(index_buffer[t + 2]));
    for (int c = 0; c < 3; ++c) {
      AVATAR_CHECK_AS(ModelLoad, index_buffer[t + c] < static_cast<uint32_t>(kVertexCount))
          << source << ": triangle index out of range";
    }
    topo.triangles.push_back(tri);
  }
  FinishTopology(topo);
  return topo;
}

void FinishTopology(Topology& topo) {
  const auto& p = topo.canonical_cm;
  for (auto& tri : topo.triangles) {
    const cv::Point3f a = p[tri[0]], b = p[tri[1]], c = p[tri[2]];
    const cv::Point3f n = (b - a).cross(c - a);
    // Orient by the normal's agreement with the outward direction (away from the head centre
    // behind the face), which is robust for the side triangles too.
    const cv::Point3f centroid = (a + b + c) * (1.0f / 3.0f);
    const cv::Point3f outward = centroid - cv::Point3f(0.0f, 0.0f, -6.0f);
    if (n.dot(outward) < 0.0f) std::swap(tri[1], tri[2]);
  }
  topo.mirror.assign(p.size(), -1);
  for (size_t i = 0; i < p.size(); ++i) {
    const cv::Point3f m(-p[i].x, p[i].y, p[i].z);
    double best = 1e30;
    for (size_t j = 0; j < p.size(); ++j) {
      const cv::Point3f d = p[j] - m;
      const double dist = d.dot(d);
      if (dist < best) {
        best = dist;
        topo.mirror[i] = static_cast<int>(j);
      }
    }
  }
}

const Topology& LoadTopology(const DataPaths& paths) {
  static std::mutex mutex;
  static std::map<std::string, Topology> cache;
  std::lock_guard<std::mutex> lock(mutex);
  const std::string key = paths.Root().string();
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  const auto data = paths.Require(kMeshAssetData, "the MediaPipe canonical face mesh (morphable model topology)");
  const auto loader = paths.Require(kMeshAssetLoader, "the offsets of the MediaPipe asset bundle");
  const std::string bytes = ReadPackedAsset(data, loader, "geometry_pipeline_metadata_landmarks.binarypb");
  return cache.emplace(key, ParseTopology(bytes, data.string())).first->second;
}

}  // namespace avatar::morphable
