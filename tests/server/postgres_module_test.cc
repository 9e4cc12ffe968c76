// The PostgreSQL store is a module: programs do not load libpq until a
// postgresql:// store is opened, and a missing module is a clear error.
// (Its own process: the module is looked up once per process.)
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <string>

#include "absl/status/status.h"
#include "server/job_store.h"
#include "tests/support/test_util.h"

namespace nimbus::server {
namespace {

TEST(PostgresModule, ProgramsDoNotLoadLibpq) {
  for (const char* name : {"nimbusd", "nimbus"}) {
    const std::string libs = testing::Ldd(std::string(NIMBUS_BIN_DIR) + "/" + name);
    ASSERT_NE(libs.find("libc.so"), std::string::npos) << libs;
    EXPECT_EQ(libs.find("libpq"), std::string::npos) << name << " loads libpq:\n" << libs;
  }
}

TEST(PostgresModule, MissingModuleNamesItAndHidesThePassword) {
  setenv("NIMBUS_POSTGRES_MODULE", "/nonexistent/libnimbus_postgres.so", 1);
  auto store = OpenPostgresJobStore("postgresql://nimbus:s3cret@127.0.0.1:1/jobs");
  ASSERT_EQ(store.status().code(), absl::StatusCode::kFailedPrecondition) << store.status();
  const std::string message(store.status().message());
  EXPECT_NE(message.find("libnimbus_postgres.so"), std::string::npos) << message;
  EXPECT_NE(message.find("NIMBUS_POSTGRES_MODULE"), std::string::npos) << message;
  EXPECT_NE(message.find("/nonexistent/libnimbus_postgres.so"), std::string::npos) << message;
  EXPECT_EQ(message.find("s3cret"), std::string::npos) << message;
}

TEST(PostgresModule, OtherSchemesAreRefusedBeforeLoading) {
  auto store = OpenPostgresJobStore("mysql://nimbus@127.0.0.1/jobs");
  EXPECT_EQ(store.status().code(), absl::StatusCode::kInvalidArgument) << store.status();
}

}  // namespace
}  // namespace nimbus::server
