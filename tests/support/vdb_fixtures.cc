#include "tests/support/vdb_fixtures.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>

#include "tests/support/test_util.h"

namespace nimbus::testing {

std::string SphereVdbBytes(const std::filesystem::path& scratch) {
  openvdb::initialize();
  auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(10.0f, {0, 0, 0}, 0.5f);
  grid->setName("surface");
  openvdb::io::File file(scratch.string());
  file.write({grid});
  file.close();
  return ReadFileBytes(scratch);
}

}  // namespace nimbus::testing
