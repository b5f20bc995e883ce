#include <fstream>
#include <random>

#include <gtest/gtest.h>

#include "common/temp_dir.h"
#include "core/io/atomic_file.h"
#include "core/util/error.h"
#include "morphable_test_util.h"

namespace avatar::morphable {
namespace {

using testing::InstalledTopology;
using testing::SyntheticModel;

TEST(Topology, InstalledAssetHasTheCanonicalMesh) {
  const Topology& t = InstalledTopology();
  ASSERT_EQ(t.canonical_cm.size(), 468u);
  EXPECT_EQ(t.triangles.size(), 898u);
  EXPECT_FALSE(t.procrustes.empty());
  for (const auto& uv : t.uv) {
    EXPECT_GE(uv.x, 0.0f);
    EXPECT_LE(uv.x, 1.0f);
    EXPECT_GE(uv.y, 0.0f);
    EXPECT_LE(uv.y, 1.0f);
  }
  // Nose tip in front, forehead above the chin, the subject's right eye at negative x.
  EXPECT_GT(t.canonical_cm[4].z, 7.0f);
  EXPECT_GT(t.canonical_cm[10].y, t.canonical_cm[152].y);
  EXPECT_LT(t.canonical_cm[33].x, 0.0f);
  EXPECT_LT(t.uv[10].y, t.uv[152].y);  // v grows downwards
  // The mirror map pairs the eyes and is an involution on most vertices.
  EXPECT_EQ(t.mirror[33], 263);
  int involutive = 0;
  for (int i = 0; i < 468; ++i) involutive += t.mirror[t.mirror[i]] == i;
  EXPECT_GT(involutive, 460);
  // Every triangle faces the front half-space or the side (outward orientation).
  int front = 0;
  for (const auto& tri : t.triangles) {
    const cv::Point3f n =
        (t.canonical_cm[tri[1]] - t.canonical_cm[tri[0]]).cross(t.canonical_cm[tri[2]] - t.canonical_cm[tri[0]]);
    front += n.z > 0;
  }
  EXPECT_GT(front, 800);
}

TEST(Topology, MalformedBytesAreModelLoadErrors) {
  EXPECT_THROW(ParseTopology("", "x.binarypb"), ModelLoad);
  EXPECT_THROW(ParseTopology(std::string("\x0a\xff\xff\xff\x0f", 5), "x.binarypb"), ModelLoad);
  EXPECT_THROW(ParseTopology(std::string("\x0a\x02\x08\x00", 4), "x.binarypb"), ModelLoad);
}

TEST(Topology, MissingDataSaysToRunSetup) {
  const DataPaths paths = DataPaths::Resolve("/nonexistent/avatar-data");
  try {
    LoadTopology(paths);
    FAIL() << "expected MissingData";
  } catch (const MissingData& e) {
    EXPECT_NE(std::string(e.what()).find("setup"), std::string::npos) << e.what();
  }
}

TEST(Topology, PackedAssetListingErrors) {
  avatar::testing::TempDir dir;
  WriteBytesAtomically(dir / "a.data", "0123456789");
  WriteBytesAtomically(dir / "a.js", R"({"filename": "/x/mesh.binarypb", "start": 2, "end": 5})");
  EXPECT_EQ(ReadPackedAsset(dir / "a.data", dir / "a.js", "mesh.binarypb"), "234");
  EXPECT_THROW(ReadPackedAsset(dir / "a.data", dir / "a.js", "other.binarypb"), ModelLoad);
  WriteBytesAtomically(dir / "b.js", R"({"filename": "/x/mesh.binarypb", "start": 2, "end": 50})");
  EXPECT_THROW(ReadPackedAsset(dir / "a.data", dir / "b.js", "mesh.binarypb"), ModelLoad);
}

TEST(Model, VerticesAreLinearInTheCoefficients) {
  const MorphableModel m = SyntheticModel(InstalledTopology(), 4, 6);
  Alpha a = {0.1f, -0.2f, 0.0f, 0.05f};
  Beta b = {0.0f, 0.1f, 0.0f, -0.1f, 0.2f, 0.0f};
  const auto v0 = m.Vertices({}, {});
  const auto va = m.Vertices(a, m.ZeroBeta());
  const auto vb = m.Vertices({}, b);
  const auto vab = m.Vertices(a, b);
  for (int i = 0; i < 468; ++i) {
    const cv::Point3f lin = va[i] + vb[i] - v0[i];
    EXPECT_NEAR(vab[i].x, lin.x, 1e-6);
    EXPECT_NEAR(vab[i].y, lin.y, 1e-6);
    EXPECT_NEAR(vab[i].z, lin.z, 1e-6);
  }
  // Column k of the basis is the displacement of unit coefficient k.
  Alpha e(4, 0.0f);
  e[2] = 1.0f;
  const auto ve = m.Vertices(e, {});
  EXPECT_NEAR(ve[100].y - v0[100].y, m.identity_basis()[(3 * 100 + 1) * 4 + 2], 1e-6);
  EXPECT_THROW(m.Vertices(Alpha(3, 0.0f), {}), InvalidInput);
  EXPECT_THROW(m.Vertices({}, Beta(7, 0.0f)), InvalidInput);
}

TEST(Model, TensorVerticesMatchThePlainOnes) {
  const MorphableModel m = SyntheticModel(InstalledTopology(), 3, 5);
  const torch::Tensor alpha = torch::randn({2, 3}, torch::kFloat64) * 0.1;
  const torch::Tensor beta = torch::randn({2, 5}, torch::kFloat64) * 0.1;
  const torch::Tensor v = m.VerticesTensor(alpha, beta);
  ASSERT_EQ(v.sizes(), (std::vector<int64_t>{2, 468, 3}));
  EXPECT_EQ(v.scalar_type(), torch::kFloat64);
  for (int b = 0; b < 2; ++b) {
    Alpha a(3);
    Beta e(5);
    for (int k = 0; k < 3; ++k) a[k] = static_cast<float>(alpha[b][k].item<double>());
    for (int k = 0; k < 5; ++k) e[k] = static_cast<float>(beta[b][k].item<double>());
    const auto plain = m.Vertices(a, e);
    EXPECT_NEAR(v[b][200][0].item<double>(), plain[200].x, 1e-5);
    EXPECT_NEAR(v[b][17][2].item<double>(), plain[17].z, 1e-5);
  }
  EXPECT_THROW(m.VerticesTensor(torch::zeros({2, 4}), torch::zeros({2, 5})), InvalidInput);
}

TEST(Model, SaveLoadRoundTripKeepsEverything) {
  avatar::testing::TempDir dir;
  MorphableModel m = SyntheticModel(InstalledTopology(), 3, 5);
  m.set_provenance("unit test");
  m.set_build_info_json(R"({"k": 5})");
  m.Save(dir / "m.avmm");
  const MorphableModel r = MorphableModel::Load(dir / "m.avmm", InstalledTopology());
  EXPECT_EQ(r.num_identity(), 3);
  EXPECT_EQ(r.num_expression(), 5);
  EXPECT_EQ(r.mean(), m.mean());
  EXPECT_EQ(r.expression_basis(), m.expression_basis());
  EXPECT_EQ(r.identity_std(), m.identity_std());
  EXPECT_EQ(r.provenance(), "unit test");
  ASSERT_EQ(r.controls().size(), m.controls().size());
  EXPECT_EQ(r.Control("jawOpen").direction, m.Control("jawOpen").direction);
}

TEST(Model, BadFilesAreModelLoadErrorsNamingTheFile) {
  avatar::testing::TempDir dir;
  const MorphableModel m = SyntheticModel(InstalledTopology(), 2, 2);
  m.Save(dir / "m.avmm");
  const std::string bytes = ReadFileBytes(dir / "m.avmm");
  WriteBytesAtomically(dir / "trunc.avmm", bytes.substr(0, bytes.size() - 10));
  WriteBytesAtomically(dir / "magic.avmm", "NOTAMODEL" + bytes.substr(9));
  std::string other_version = bytes;
  other_version[8] = 9;
  WriteBytesAtomically(dir / "version.avmm", other_version);
  for (const char* name : {"trunc.avmm", "magic.avmm", "version.avmm"}) {
    try {
      MorphableModel::Load(dir / name, InstalledTopology());
      FAIL() << name;
    } catch (const ModelLoad& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(MorphableModel::Load(dir / "missing.avmm", InstalledTopology()), Io);
}

TEST(Model, ControlsCombineLinearlyAndRejectUnknownNames) {
  const MorphableModel m = SyntheticModel(InstalledTopology(), 2, 12);
  const Beta b = m.ExpressionFromControls({{"jawOpen", 0.5f}, {"smile", 2.0f}});
  for (int k = 0; k < 12; ++k) {
    EXPECT_NEAR(b[k], 0.5f * m.Control("jawOpen").direction[k] + 2.0f * m.Control("smile").direction[k], 1e-6);
  }
  EXPECT_THROW(m.ExpressionFromControls({{"wink", 1.0f}}), InvalidInput);
  EXPECT_THROW(m.ExpressionFromControls({{"smile", std::nanf("")}}), InvalidInput);
}

}  // namespace
}  // namespace avatar::morphable
