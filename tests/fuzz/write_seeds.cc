// Writes the generated seeds of tests/fuzz/corpus: a tetrahedron in every
// mesh format and a tiny density VDB, all written by Nimbus itself so the
// seeds match what real clients upload. Usage: fuzz_write_seeds CORPUS_DIR
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "core/io/mesh_io.h"
#include "core/io/vdb_io.h"

namespace {

namespace fs = std::filesystem;

bool WriteFile(const fs::path& path, const std::string& bytes) {
  fs::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary);
  out << bytes;
  return bool(out);
}

nimbus::TriangleMesh Tetrahedron() {
  nimbus::TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  mesh.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return mesh;
}

bool WriteMeshes(const fs::path& dir) {
  using nimbus::MeshFormat;
  const nimbus::TriangleMesh mesh = Tetrahedron();
  const struct {
    const char* file;
    MeshFormat format;
  } seeds[] = {{"obj_fuzzer/tetra.obj", MeshFormat::kObj},
               {"ply_fuzzer/tetra_ascii.ply", MeshFormat::kPlyAscii},
               {"ply_fuzzer/tetra_binary.ply", MeshFormat::kPlyBinary},
               {"stl_fuzzer/tetra_ascii.stl", MeshFormat::kStlAscii},
               {"stl_fuzzer/tetra_binary.stl", MeshFormat::kStlBinary}};
  for (const auto& seed : seeds)
    if (!WriteFile(dir / seed.file, SerializeMesh(mesh, seed.format))) return false;
  return true;
}

// A 4^3 grid with a few visited voxels. No ".vdb": the repository ignores it.
bool WriteVdb(const fs::path& dir) {
  nimbus::CountGrid counts({4, 4, 4});
  counts.AddKey(counts.Key(0, 0, 0), 3);
  counts.AddKey(counts.Key(1, 2, 3), 1);
  counts.AddKey(counts.Key(3, 3, 3), 2);
  const nimbus::GridFrame frame{{4, 4, 4}, {{-1, -1, -1}, {1, 1, 1}}};
  auto bytes = nimbus::DensityVdbBytes(counts, frame, {}, {{"nimbus_seed", std::string("fuzz")}});
  return bytes.ok() && WriteFile(dir / "vdb_fuzzer/tiny_density", *bytes);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]);
    return 2;
  }
  const bool ok = WriteMeshes(argv[1]) && WriteVdb(argv[1]);
  if (!ok) std::fprintf(stderr, "could not write the seeds\n");
  return ok ? 0 : 1;
}
