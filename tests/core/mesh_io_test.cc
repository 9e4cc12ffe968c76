#include "core/io/mesh_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstring>
#include <fstream>

#include "absl/strings/str_cat.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;

std::string Message(const absl::Status& s) { return std::string(s.message()); }

void WriteFile(const std::filesystem::path& path, const std::string& data) {
  std::ofstream out(path, std::ios::binary);
  out.write(data.data(), std::streamsize(data.size()));
}

// A unit cube corner tetrahedron plus a quad-split square: coordinates are
// exact in float, so every format round-trips them bit for bit.
TriangleMesh SmallMesh() {
  TriangleMesh m;
  m.vertices = {{0, 0, 0},   {1, 0, 0},   {0, 1, 0},     {0, 0, 1},
                {2, 2, 0.5}, {3, 2, 0.5}, {3, 3.25, 0.5}};
  m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}, {4, 5, 6}};
  return m;
}

// Triangles as corner positions, so meshes with and without shared
// vertices (STL) compare equal.
std::vector<std::array<Vec3, 3>> Corners(const TriangleMesh& m) {
  std::vector<std::array<Vec3, 3>> out;
  for (const auto& t : m.triangles)
    out.push_back({m.vertices[t[0]], m.vertices[t[1]], m.vertices[t[2]]});
  return out;
}

TEST(MeshIo, LoadsTheExampleMeshes) {
  const absl::StatusOr<TriangleMesh> cow = LoadMesh(testing::SourcePath("examples/meshes/cow.obj"));
  ASSERT_TRUE(cow.ok()) << cow.status();
  EXPECT_EQ(cow->vertices.size(), 2903u);
  EXPECT_EQ(cow->triangles.size(), 5804u);
  // Suzanne has quads ("f a//a b//b c//c d//d"), split in two each.
  const absl::StatusOr<TriangleMesh> monkey =
      LoadMesh(testing::SourcePath("examples/meshes/suzanne.obj"));
  ASSERT_TRUE(monkey.ok()) << monkey.status();
  EXPECT_EQ(monkey->triangles.size(), 968u);
}

TEST(MeshIo, ObjFaceSyntaxes) {
  const std::string text =
      "# comment\n"
      "o thing\n"
      "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\n"
      "vt 0 0\nvn 0 0 1\n"
      "f 1/1/1 2/1/1 3/1/1 4/1/1\n"  // quad with texture and normal
      "f -4//1 -2//1 -1//1\r\n"      // relative indices, CRLF
      "l 1 2\n";
  const absl::StatusOr<TriangleMesh> m = ParseObj(text, "inline.obj");
  ASSERT_TRUE(m.ok()) << m.status();
  ASSERT_EQ(m->triangles.size(), 3u);
  EXPECT_EQ(m->triangles[0], (std::array<uint32_t, 3>{0, 1, 2}));
  EXPECT_EQ(m->triangles[1], (std::array<uint32_t, 3>{0, 2, 3}));
  EXPECT_EQ(m->triangles[2], (std::array<uint32_t, 3>{0, 2, 3}));
}

TEST(MeshIo, RoundTripsEveryFormat) {
  testing::TempDir dir;
  const TriangleMesh mesh = SmallMesh();
  const std::pair<MeshFormat, std::string> cases[] = {{MeshFormat::kObj, "m.obj"},
                                                      {MeshFormat::kPlyAscii, "a.ply"},
                                                      {MeshFormat::kPlyBinary, "b.ply"},
                                                      {MeshFormat::kStlAscii, "a.stl"},
                                                      {MeshFormat::kStlBinary, "b.stl"}};
  for (const auto& [format, name] : cases) {
    ASSERT_TRUE(SaveMesh(mesh, dir / name, format).ok());
    const absl::StatusOr<TriangleMesh> back = LoadMesh(dir / name);
    ASSERT_TRUE(back.ok()) << name << ": " << back.status();
    EXPECT_EQ(Corners(*back), Corners(mesh)) << name;
    if (format != MeshFormat::kStlAscii && format != MeshFormat::kStlBinary) {
      EXPECT_EQ(back->vertices, mesh.vertices) << name;
      EXPECT_EQ(back->triangles, mesh.triangles) << name;
    }
  }
}

TEST(MeshIo, BigEndianPlyWithExtraProperties) {
  // Hand-built: uchar colour and a double before x, an extra element, and
  // a quad face with a ushort count.
  std::string data =
      "ply\nformat binary_big_endian 1.0\ncomment test\n"
      "element vertex 4\nproperty uchar red\nproperty double weight\n"
      "property float x\nproperty float y\nproperty float z\n"
      "element face 1\nproperty list ushort int vertex_indices\n"
      "element edge 1\nproperty int a\nproperty int b\nend_header\n";
  auto put = [&](const void* p, size_t n) {
    const char* c = static_cast<const char*>(p);
    for (size_t i = 0; i < n; ++i) data += c[n - 1 - i];  // to big-endian
  };
  const float xyz[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0.5f}};
  for (const auto& v : xyz) {
    const uint8_t red = 200;
    const double weight = 0.25;
    put(&red, 1);
    put(&weight, 8);
    for (float c : v) put(&c, 4);
  }
  const uint16_t count = 4;
  put(&count, 2);
  for (int32_t i : {0, 1, 2, 3}) put(&i, 4);
  for (int32_t i : {0, 1}) put(&i, 4);
  const absl::StatusOr<TriangleMesh> m = ParsePly(data, "be.ply");
  ASSERT_TRUE(m.ok()) << m.status();
  ASSERT_EQ(m->vertices.size(), 4u);
  EXPECT_EQ(m->vertices[3], (Vec3{0, 1, 0.5}));
  EXPECT_EQ(m->triangles.size(), 2u);
}

TEST(MeshIo, AsciiPlyWithOtherElements) {
  const std::string text =
      "ply\r\nformat ascii 1.0\r\nelement vertex 3\r\nproperty float x\r\nproperty float y\r\n"
      "property float z\r\nproperty float nx\r\nelement material 1\r\nproperty int id\r\n"
      "element face 1\r\nproperty list uchar int vertex_index\r\nend_header\r\n"
      "0 0 0 9\r\n1 0 0 9\r\n0 1 0 9\r\n\r\n7\r\n3 0 1 2\r\n";
  const absl::StatusOr<TriangleMesh> m = ParsePly(text, "crlf.ply");
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->triangles.size(), 1u);
}

TEST(MeshIo, ErrorsNameTheFileAndPlace) {
  testing::TempDir dir;
  // No faces at all.
  WriteFile(dir / "empty.obj", "v 0 0 0\nv 1 0 0\n");
  absl::Status s = LoadMesh(dir / "empty.obj").status();
  EXPECT_THAT(Message(s), AllOf(HasSubstr("empty.obj"), HasSubstr("empty")));
  // Every face has zero area.
  WriteFile(dir / "flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n");
  s = LoadMesh(dir / "flat.obj").status();
  EXPECT_THAT(Message(s), AllOf(HasSubstr("flat.obj"), HasSubstr("degenerate")));
  // Non-finite coordinates, with the line.
  WriteFile(dir / "nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
  s = LoadMesh(dir / "nan.obj").status();
  EXPECT_THAT(Message(s), AllOf(HasSubstr("nan.obj:2:"), HasSubstr("non-finite")));
  WriteFile(dir / "inf.stl",
            "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n"
            "vertex inf 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid x\n");
  s = LoadMesh(dir / "inf.stl").status();
  EXPECT_THAT(Message(s), AllOf(HasSubstr("inf.stl:5:"), HasSubstr("non-finite")));
  // Bad indices.
  WriteFile(dir / "index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
  s = LoadMesh(dir / "index.obj").status();
  EXPECT_THAT(Message(s), AllOf(HasSubstr("index.obj:4:"), HasSubstr("out of range")));
  WriteFile(dir / "zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
  EXPECT_THAT(Message(LoadMesh(dir / "zero.obj").status()), HasSubstr("zero.obj:4:"));
  const std::string ply_bad =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n";
  EXPECT_THAT(Message(ParsePly(ply_bad, "bad.ply").status()),
              AllOf(HasSubstr("bad.ply:13"), HasSubstr("out of range")));
  // Truncated binaries report the byte offset.
  std::string stl = SerializeMesh(SmallMesh(), MeshFormat::kStlBinary);
  stl.resize(stl.size() - 30);
  WriteFile(dir / "cut.stl", stl);
  s = LoadMesh(dir / "cut.stl").status();
  EXPECT_THAT(Message(s), AllOf(HasSubstr("cut.stl"), HasSubstr("truncated"),
                                HasSubstr("byte offset 284")));  // 84 + 4 * 50
  std::string ply = SerializeMesh(SmallMesh(), MeshFormat::kPlyBinary);
  ply.resize(ply.size() - 7);
  WriteFile(dir / "cut.ply", ply);
  s = LoadMesh(dir / "cut.ply").status();
  EXPECT_THAT(Message(s), AllOf(HasSubstr("cut.ply"), HasSubstr("truncated"),
                                HasSubstr("byte offset"), HasSubstr("face 4")));
  WriteFile(dir / "tiny.stl", "not a mesh");
  EXPECT_THAT(Message(LoadMesh(dir / "tiny.stl").status()), HasSubstr("truncated"));
  // Header problems.
  EXPECT_THAT(Message(ParsePly("ply\nformat ascii 1.0\nelement vertex 0\n", "h.ply").status()),
              HasSubstr("end_header"));
  EXPECT_THAT(Message(ParsePly("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                               "end_header\n0\n",
                               "h.ply")
                          .status()),
              HasSubstr("x, y, z"));
  WriteFile(dir / "mesh.xyz", "v 0 0 0\n");
  EXPECT_THAT(Message(LoadMesh(dir / "mesh.xyz").status()), HasSubstr("unknown mesh format"));
  EXPECT_EQ(LoadMesh(dir / "missing.obj").status().code(), absl::StatusCode::kNotFound);
}

// A face of n corners is n - 2 triangles; past kMaxPolygonCorners it is
// refused with its line (OBJ, ASCII PLY) or its face (binary PLY).
TEST(MeshIo, HugePolygonsAreRefusedWithTheLimit) {
  auto obj = [](int corners) {
    std::string text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf";
    for (int c = 0; c < corners; ++c) absl::StrAppend(&text, " ", c % 4 + 1);
    return text + "\n";
  };
  auto most = ParseObj(obj(4096), "most.obj");
  ASSERT_TRUE(most.ok()) << most.status();
  EXPECT_EQ(most->triangles.size(), 4094u);
  EXPECT_THAT(Message(ParseObj(obj(4097), "big.obj").status()),
              HasSubstr("big.obj:5: face has 4097 corners; at most 4096 are allowed"));
  EXPECT_THAT(Message(ParseObj(obj(1'000'000), "huge.obj").status()),
              HasSubstr("huge.obj:5: face has 1000000 corners; at most 4096"));
  std::string ply =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n"
      "0 0 0\n1 0 0\n0 1 0\n5000";
  for (int c = 0; c < 5000; ++c) absl::StrAppend(&ply, " ", c % 3);
  EXPECT_THAT(Message(ParsePly(ply + "\n", "big.ply").status()),
              HasSubstr("big.ply:13: face has 5000 corners; at most 4096"));
}

TEST(MeshIo, FileTypeFromNamesAndWords) {
  EXPECT_EQ(MeshFileTypeFromName("cow.obj"), MeshFileType::kObj);
  EXPECT_EQ(MeshFileTypeFromName("x/y/Mesh.PLY"), MeshFileType::kPly);
  EXPECT_EQ(MeshFileTypeFromName(".stl"), MeshFileType::kStl);
  EXPECT_EQ(MeshFileTypeFromName("STL"), MeshFileType::kStl);
  EXPECT_EQ(MeshFileTypeFromName("smoke.vdb"), MeshFileType::kUnknown);
  EXPECT_EQ(MeshFileTypeFromName("a.obj/blob"), MeshFileType::kUnknown);
  EXPECT_EQ(MeshFileTypeFromName(""), MeshFileType::kUnknown);
}

// Content-addressed assets have no extension: the caller says the format,
// PLY and STL are also recognised by content, and messages use the name the
// caller gives instead of the path.
TEST(MeshIo, LoadsExtensionlessFilesByHintOrContent) {
  testing::TempDir dir;
  const TriangleMesh mesh = SmallMesh();
  const std::pair<MeshFormat, std::string> cases[] = {{MeshFormat::kPlyAscii, "ply_a"},
                                                      {MeshFormat::kPlyBinary, "ply_b"},
                                                      {MeshFormat::kStlAscii, "stl_a"},
                                                      {MeshFormat::kStlBinary, "stl_b"},
                                                      {MeshFormat::kObj, "obj"}};
  for (const auto& [format, name] : cases) {
    ASSERT_TRUE(SaveMesh(mesh, dir / name, format).ok());
    const absl::StatusOr<TriangleMesh> sniffed = LoadMesh(dir / name);
    if (format == MeshFormat::kObj) {
      // OBJ has no signature: without a hint it stays unknown.
      EXPECT_THAT(Message(sniffed.status()), HasSubstr("unknown mesh format")) << name;
    } else {
      ASSERT_TRUE(sniffed.ok()) << name << ": " << sniffed.status();
      EXPECT_EQ(Corners(*sniffed), Corners(mesh)) << name;
    }
  }
  const absl::StatusOr<TriangleMesh> obj =
      LoadMesh(dir / "obj", {MeshFileTypeFromName("cow.obj"), "cow.obj"});
  ASSERT_TRUE(obj.ok()) << obj.status();
  EXPECT_EQ(obj->vertices, mesh.vertices);
  // The hint outranks the path's extension; a PLY header outranks both.
  ASSERT_TRUE(SaveMesh(mesh, dir / "really_obj.stl", MeshFormat::kObj).ok());
  EXPECT_TRUE(LoadMesh(dir / "really_obj.stl", {MeshFileType::kObj, ""}).ok());
  EXPECT_TRUE(LoadMesh(dir / "ply_b", {MeshFileType::kObj, "x.obj"}).ok());
  // Messages name the display name, not the path.
  WriteFile(dir / "blob", "v 0 0 0\nv 1 0 0\nf 1 2 3\n");
  const absl::Status s = LoadMesh(dir / "blob", {MeshFileType::kObj, "cow.obj (sha256 3fa2)"}).status();
  EXPECT_THAT(Message(s), HasSubstr("cow.obj (sha256 3fa2):3: face index 3 out of range"));
  EXPECT_EQ(Message(s).find(dir.path().string()), std::string::npos) << Message(s);
  EXPECT_EQ(Message(LoadMesh(dir / "gone", {MeshFileType::kObj, "gone.obj"}).status()),
            "gone.obj: cannot open mesh file");
}

TEST(MeshIo, ValidateMeshRejectsBadIndicesAndNonFinite) {
  TriangleMesh m = SmallMesh();
  EXPECT_TRUE(ValidateMesh(m, "m").ok());
  m.triangles.push_back({0, 1, 99});
  EXPECT_THAT(Message(ValidateMesh(m, "m")), HasSubstr("uses vertex 99"));
  m = SmallMesh();
  m.vertices[2].y = std::numeric_limits<double>::infinity();
  EXPECT_THAT(Message(ValidateMesh(m, "m")), HasSubstr("vertex 2"));
}

// Found by the PLY fuzzer: an element with a huge count and no properties
// read no bytes per instance and looped for ~10^18 instances.
TEST(MeshIo, PlyElementCountsAreCheckedAgainstTheFile) {
  std::ifstream in(testing::SourcePath(
                       "tests/fuzz/corpus/ply_fuzzer/crash-binary-element-without-properties.ply"),
                   std::ios::binary);
  const std::string hostile((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_FALSE(hostile.empty());
  EXPECT_THAT(Message(ParsePly(hostile, "h.ply").status()), HasSubstr("no properties"));
  // A binary element claiming more instances than bytes left is truncated.
  std::string big =
      "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\n"
      "property float x\nproperty float y\nproperty float z\nend_header\n";
  big += std::string(12, '\0');
  EXPECT_THAT(Message(ParsePly(big, "b.ply").status()), HasSubstr("truncated binary PLY"));
}

// A second vertex element once paired the first one's x, y, z indices with
// the second one's shorter instances (found by the 10-minute fuzz run).
TEST(MeshIo, PlyWithTwoVertexElementsIsRefused) {
  std::ifstream in(
      testing::SourcePath("tests/fuzz/corpus/ply_fuzzer/crash-two-vertex-elements.ply"),
      std::ios::binary);
  const std::string hostile((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_FALSE(hostile.empty());
  EXPECT_THAT(Message(ParsePly(hostile, "h.ply").status()),
              HasSubstr("more than one 'vertex' element"));
  const std::string two_faces =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
      "element face 1\nproperty uchar n\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n1\n";
  EXPECT_THAT(Message(ParsePly(two_faces, "f.ply").status()),
              HasSubstr("more than one 'face' element"));
}

}  // namespace
}  // namespace nimbus
