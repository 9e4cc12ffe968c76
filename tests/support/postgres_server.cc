#include "tests/support/postgres_server.h"

#include <pwd.h>
#include <stdlib.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <pqxx/pqxx>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <fstream>
#include <mutex>
#include <sstream>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"

namespace nimbus::testing {
namespace {

namespace fs = std::filesystem;

// PostgreSQL refuses to run as root; as root the server runs as `postgres`.
bool AsRoot() { return ::geteuid() == 0; }

std::string AsServerUser(const std::string& command) {
  return AsRoot() ? "runuser -u postgres -- " + command : command;
}

absl::Status Run(const std::string& command, const fs::path& log) {
  const std::string full = absl::StrCat(command, " >>", log.string(), " 2>&1");
  const int rc = std::system(full.c_str());
  if (rc == 0) return absl::OkStatus();
  std::ifstream in(log);
  std::stringstream text;
  text << in.rdbuf();
  std::string tail = text.str();
  if (tail.size() > 2000) tail = tail.substr(tail.size() - 2000);
  return absl::InternalError(absl::StrCat("`", command, "` failed (", rc, "): ", tail));
}

void ChownToServerUser(const fs::path& path) {
  if (!AsRoot()) return;
  if (const passwd* pw = ::getpwnam("postgres"))
    (void)::chown(path.c_str(), pw->pw_uid, pw->pw_gid);
}

// An initdb'd data folder kept between test processes: initdb costs about a
// second, a copy of its output a tenth of that.
absl::StatusOr<fs::path> TemplateDataDir(const fs::path& bin) {
  const fs::path tmpl = fs::temp_directory_path() /
                        absl::StrCat("nimbus-pg-template-", ::geteuid(), "-",
                                     bin.parent_path().filename().string());
  if (fs::exists(tmpl / "PG_VERSION")) return tmpl;
  std::string scratch = (fs::temp_directory_path() / "nimbus-pg-init-XXXXXX").string();
  if (::mkdtemp(scratch.data()) == nullptr)
    return absl::InternalError("cannot create a folder for initdb");
  ChownToServerUser(scratch);
  const fs::path data = fs::path(scratch) / "data";
  absl::Status s = Run(AsServerUser(absl::StrCat((bin / "initdb").string(), " -D ", data.string(),
                                                 " -A trust -U postgres -E UTF8 --no-locale "
                                                 "--no-sync --no-instructions")),
                       fs::path(scratch + ".log"));
  if (!s.ok()) return s;
  // Whoever renames first wins; a loser's copy is simply dropped.
  std::error_code ec;
  fs::rename(data, tmpl, ec);
  fs::remove_all(scratch, ec);
  fs::remove(fs::path(scratch + ".log"), ec);
  if (!fs::exists(tmpl / "PG_VERSION"))
    return absl::InternalError(absl::StrCat("no PostgreSQL template at ", tmpl.string()));
  return tmpl;
}

}  // namespace

fs::path PostgresBinDir() {
  std::vector<fs::path> found;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator("/usr/lib/postgresql", ec)) {
    const fs::path bin = entry.path() / "bin";
    if (fs::exists(bin / "initdb") && fs::exists(bin / "pg_ctl")) found.push_back(bin);
  }
  if (found.empty()) return {};
  // Newest major version: "15" sorts after "13" as numbers, not as text.
  std::sort(found.begin(), found.end(), [](const fs::path& a, const fs::path& b) {
    return std::atoi(a.parent_path().filename().c_str()) <
           std::atoi(b.parent_path().filename().c_str());
  });
  return found.back();
}

// The folder of initdb and pg_ctl, or UNAVAILABLE saying why no test
// server can run here.
static absl::StatusOr<fs::path> ServerBinDir() {
  const fs::path bin = PostgresBinDir();
  if (bin.empty())
    return absl::UnavailableError(
        "PostgreSQL binaries (initdb, pg_ctl) not found under /usr/lib/postgresql; install "
        "the Debian package `postgresql` (scripts/install_deps.sh does)");
  if (AsRoot() && ::getpwnam("postgres") == nullptr)
    return absl::UnavailableError("running as root but there is no `postgres` user to run "
                                  "the test server as");
  return bin;
}

absl::StatusOr<std::unique_ptr<PostgresServer>> PostgresServer::Start() {
  absl::StatusOr<fs::path> bin = ServerBinDir();
  if (!bin.ok()) return bin.status();
  std::string dir = (fs::temp_directory_path() / "nimbus-pg-XXXXXX").string();
  if (::mkdtemp(dir.data()) == nullptr)
    return absl::InternalError("cannot create a folder for the PostgreSQL server");
  std::unique_ptr<PostgresServer> server(new PostgresServer(dir, *bin));
  if (absl::Status s = server->Init(/*watchdog=*/true); !s.ok()) return s;
  return server;
}

absl::Status PostgresServer::StartDetached(const fs::path& dir) {
  absl::StatusOr<fs::path> bin = ServerBinDir();
  if (!bin.ok()) return bin.status();
  StopDetached(dir);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create ", dir.string()));
  PostgresServer server(dir, *bin);
  absl::Status s = server.Init(/*watchdog=*/false);
  server.attached_ = s.ok();  // left running for the run's tests
  return s;
}

void PostgresServer::StopDetached(const fs::path& dir) {
  const fs::path bin = PostgresBinDir();
  if (!bin.empty() && fs::exists(dir / "data" / "postmaster.pid"))
    (void)Run(AsServerUser(absl::StrCat((bin / "pg_ctl").string(), " -D ",
                                        (dir / "data").string(), " -m immediate -w stop")),
              "/dev/null");
  std::error_code ec;
  fs::remove_all(dir, ec);
}

std::unique_ptr<PostgresServer> PostgresServer::Attach(const fs::path& dir) {
  // The first line of postmaster.pid is the server's pid; EPERM: alive,
  // but another user's (the `postgres` user when tests run as root).
  std::ifstream pid_file(dir / "data" / "postmaster.pid");
  pid_t pid = 0;
  if (!(pid_file >> pid) || pid <= 0 || (::kill(pid, 0) != 0 && errno != EPERM)) return nullptr;
  std::unique_ptr<PostgresServer> server(new PostgresServer(dir, PostgresBinDir()));
  server->attached_ = true;
  return server;
}

absl::Status PostgresServer::Init(bool watchdog) {
  ChownToServerUser(dir_);
  absl::StatusOr<fs::path> tmpl = TemplateDataDir(bin_);
  if (!tmpl.ok()) return tmpl.status();
  const fs::path data = dir_ / "data";
  const fs::path log = dir_ / "server.log";  // written by the server's user
  if (absl::Status s =
          Run(absl::StrCat("cp -a ", tmpl->string(), " ", data.string()), dir_ / "setup.log");
      !s.ok())
    return s;
  // Only a unix socket in our own folder: nothing to collide with, no port
  // to guess. fsync off: a test database need not survive a power cut.
  const std::string options = absl::StrCat(
      "-k ", dir_.string(), " -c listen_addresses='' -F -c max_connections=300 ",
      "-c shared_buffers=16MB");
  if (absl::Status s = Run(AsServerUser(absl::StrCat((bin_ / "pg_ctl").string(), " -D ",
                                                     data.string(), " -o \"", options,
                                                     "\" -w -t 60 -l ", log.string(), " start")),
                           dir_ / "pg_ctl.log");
      !s.ok())
    return s;
  running_ = true;
  if (watchdog) StartWatchdog();
  return absl::OkStatus();
}

void PostgresServer::StartWatchdog() {
  // Built before fork: the child only reads, then execs a shell.
  const std::string stop = absl::StrCat(
      AsServerUser(absl::StrCat((bin_ / "pg_ctl").string(), " -D ", (dir_ / "data").string(),
                                " -m immediate -w stop")),
      " >/dev/null 2>&1; rm -rf ", dir_.string());
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) return;
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(fds[1]);
    char byte;
    // EOF once every copy of the write end is closed: our destructor, or
    // the end of this process (nimbusd children never hold it: CLOEXEC).
    while (::read(fds[0], &byte, 1) != 0) {
    }
    ::execl("/bin/sh", "sh", "-c", stop.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  ::close(fds[0]);
  if (pid < 0) {
    ::close(fds[1]);
    return;
  }
  watchdog_fd_ = fds[1];
  watchdog_ = pid;
}

PostgresServer::~PostgresServer() {
  if (attached_) return;
  if (watchdog_ > 0) {
    // The watchdog stops the server and removes the folder; wait for it.
    ::close(watchdog_fd_);
    int status = 0;
    ::waitpid(watchdog_, &status, 0);
    return;
  }
  if (running_) {
    (void)Run(AsServerUser(absl::StrCat((bin_ / "pg_ctl").string(), " -D ",
                                        (dir_ / "data").string(), " -m immediate -w stop")),
              dir_ / "pg_ctl.log");
  }
  std::error_code ec;
  fs::remove_all(dir_, ec);
}

std::string PostgresServer::Url(const std::string& database) const {
  return absl::StrCat("postgresql:///", database, "?host=", dir_.string(), "&user=postgres");
}

absl::StatusOr<std::string> PostgresServer::NewDatabase() {
  // The pid and the clock: a shared server outlives test processes, whose
  // pids can come round again.
  const std::string name =
      absl::StrCat("nimbus_test_", ::getpid(), "_", next_db_++, "_",
                   std::chrono::steady_clock::now().time_since_epoch().count());
  try {
    pqxx::connection c(Url());
    pqxx::nontransaction n(c);
    n.exec("CREATE DATABASE " + name);
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat("CREATE DATABASE ", name, ": ", e.what()));
  }
  return Url(name);
}

PostgresServer* PostgresServer::Shared(std::string* why) {
  static std::mutex mu;
  static std::unique_ptr<PostgresServer> server;
  static absl::Status failure;
  std::lock_guard<std::mutex> lock(mu);
  if (server == nullptr && failure.ok()) {
    if (const char* dir = std::getenv(kFixtureDirEnv); dir != nullptr && *dir != 0)
      server = Attach(dir);
  }
  if (server == nullptr && failure.ok()) {
    absl::StatusOr<std::unique_ptr<PostgresServer>> s = Start();
    if (s.ok()) {
      server = std::move(*s);
    } else {
      failure = s.status();
    }
  }
  if (server == nullptr && why != nullptr) *why = std::string(failure.message());
  return server.get();
}

}  // namespace nimbus::testing
