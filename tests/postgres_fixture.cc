// ctest's PostgreSQL fixture: `postgres_fixture start DIR` leaves one
// server running in DIR for the whole run, `postgres_fixture stop DIR`
// stops it and removes DIR (tests/support/postgres_server.h). Without
// PostgreSQL, start says so and succeeds: the tests then skip as they do
// outside ctest.
#include <cstdio>
#include <cstring>

#include "tests/support/postgres_server.h"

int main(int argc, char** argv) {
  using nimbus::testing::PostgresServer;
  if (argc != 3 || (std::strcmp(argv[1], "start") != 0 && std::strcmp(argv[1], "stop") != 0)) {
    std::fprintf(stderr, "usage: postgres_fixture start|stop DIR\n");
    return 2;
  }
  if (std::strcmp(argv[1], "stop") == 0) {
    PostgresServer::StopDetached(argv[2]);
    return 0;
  }
  const absl::Status s = PostgresServer::StartDetached(argv[2]);
  if (s.ok()) {
    std::printf("PostgreSQL for this run: %s\n", argv[2]);
    return 0;
  }
  // Each test process then tries a server of its own, and reports why not.
  std::printf("no shared PostgreSQL server: %s\n", std::string(s.message()).c_str());
  return 0;
}
