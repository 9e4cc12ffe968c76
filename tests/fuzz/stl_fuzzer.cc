// STL bytes -> ParseStl (the in-memory reader behind LoadMesh) -> ValidateMesh.
#include "core/io/mesh_io.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  auto mesh = nimbus::ParseStl(nimbus::fuzz::AsView(data, size), "fuzz.stl");
  if (mesh.ok()) {
    (void)nimbus::ValidateMesh(*mesh, "fuzz.stl");
    (void)mesh->GetBounds();
    (void)mesh->SurfaceArea();
  }
  return 0;
}
