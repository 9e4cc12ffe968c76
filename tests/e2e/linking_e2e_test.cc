// The programs link gRPC, Protobuf, Abseil and OpenSSL as the shared
// libraries the OpenVDB module (libnimbus_vdb.so) and the PostgreSQL module
// load too, so a process that loads a module holds one copy of each.
#include <gtest/gtest.h>

#include <string>

#include "tests/support/test_util.h"

namespace nimbus {
namespace {

TEST(Linking, ProgramsAndTheVdbModuleShareTheSharedLibraries) {
  const std::string bin(NIMBUS_BIN_DIR);
  const std::string module = bin + "/../lib/nimbus/libnimbus_vdb.so";
  for (const std::string& object : {bin + "/nimbus", bin + "/nimbusd", module}) {
    const std::string libs = testing::Ldd(object);
    ASSERT_NE(libs.find("libc.so"), std::string::npos) << object << ":\n" << libs;
    EXPECT_NE(libs.find("libabsl_base.so"), std::string::npos) << object << ":\n" << libs;
  }
  for (const char* program : {"/nimbus", "/nimbusd"}) {
    const std::string libs = testing::Ldd(bin + program);
    for (const char* lib : {"libgrpc++.so", "libprotobuf.so", "libcrypto.so", "libssl.so"})
      EXPECT_NE(libs.find(lib), std::string::npos) << program << " lacks " << lib << ":\n" << libs;
  }
}

}  // namespace
}  // namespace nimbus
