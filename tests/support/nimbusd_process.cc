#include "tests/support/nimbusd_process.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/inotify.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>

#include "absl/strings/str_cat.h"

namespace nimbus::testing {

namespace {

constexpr char kPortFile[] = "nimbusd.port";
// Only a guard against a wedged start; nimbusd is normally up at once.
constexpr auto kStartTimeout = std::chrono::seconds(60);

// Closes a file descriptor when it goes out of scope.
struct Fd {
  int fd;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

}  // namespace

NimbusdProcess::NimbusdProcess(std::filesystem::path data_dir, std::vector<std::string> args)
    : data_dir_(std::move(data_dir)), args_(std::move(args)) {}

NimbusdProcess::~NimbusdProcess() { Kill(); }

std::string NimbusdProcess::target() const { return absl::StrCat("127.0.0.1:", port_); }

absl::Status NimbusdProcess::Start(int port) {
  if (running()) return absl::FailedPreconditionError("nimbusd is already running");
  std::error_code ec;
  std::filesystem::create_directories(data_dir_, ec);
  if (ec) return absl::InternalError(absl::StrCat(data_dir_.string(), ": ", ec.message()));
  const std::filesystem::path port_file = data_dir_ / kPortFile;
  std::filesystem::remove(port_file, ec);

  std::vector<std::string> argv = {std::string(NIMBUS_BIN_DIR) + "/nimbusd",
                                   "--listen",
                                   absl::StrCat(listen_host_, ":", port),
                                   "--port-file",
                                   port_file.string(),
                                   "--data-dir",
                                   data_dir_.string()};
  argv.insert(argv.end(), args_.begin(), args_.end());
  std::vector<char*> c_argv;
  for (std::string& a : argv) c_argv.push_back(a.data());
  c_argv.push_back(nullptr);

  const std::string log = log_file_.string();
  pid_ = ::fork();
  if (pid_ < 0) return absl::InternalError("fork failed");
  if (pid_ == 0) {
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);  // never outlive a crashed test
    if (const int fd =
            log.empty() ? -1 : ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
        fd >= 0) {
      ::dup2(fd, 1);
      ::dup2(fd, 2);
    }
    ::execv(c_argv[0], c_argv.data());
    ::_exit(127);
  }
  absl::Status s = AwaitPortFile(port_file);
  if (!s.ok()) Kill();
  return s;
}

// Waits for nimbusd to write its port file (it does so once listening),
// woken by inotify rather than polling; the poll timeout only lets us
// notice a child that died instead.
absl::Status NimbusdProcess::AwaitPortFile(const std::filesystem::path& port_file) {
  Fd watch{::inotify_init1(IN_CLOEXEC)};
  if (watch.fd < 0 ||
      ::inotify_add_watch(watch.fd, data_dir_.c_str(), IN_MOVED_TO | IN_CLOSE_WRITE) < 0)
    return absl::InternalError("inotify on " + data_dir_.string() + " failed");
  const auto deadline = std::chrono::steady_clock::now() + kStartTimeout;
  while (!std::filesystem::exists(port_file)) {
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      return absl::UnavailableError(absl::StrCat("nimbusd exited during start-up (status ",
                                                 status, "); see its log above"));
    }
    if (std::chrono::steady_clock::now() > deadline)
      return absl::DeadlineExceededError("nimbusd did not report its port in time");
    pollfd p{watch.fd, POLLIN, 0};
    if (::poll(&p, 1, 250) > 0) {
      char events[4096];
      (void)::read(watch.fd, events, sizeof events);  // drain; the file is checked above
    }
  }
  std::ifstream in(port_file);
  int port = 0;
  if (!(in >> port) || port <= 0)
    return absl::InternalError("unreadable port file " + port_file.string());
  port_ = port;
  return absl::OkStatus();
}

void NimbusdProcess::Kill() {
  if (pid_ <= 0) return;
  ::kill(pid_, SIGKILL);
  int status;
  ::waitpid(pid_, &status, 0);
  pid_ = -1;
}

int NimbusdProcess::Stop() {
  if (pid_ <= 0) return -1;
  ::kill(pid_, SIGTERM);
  int status = 0;
  ::waitpid(pid_, &status, 0);
  pid_ = -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace nimbus::testing
