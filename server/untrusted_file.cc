#include "server/untrusted_file.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <set>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/string_view.h"
#include "absl/strings/strip.h"
#include "core/io/mesh_io.h"
#include "core/io/vdb_io.h"
#include "proto/asset_paths.h"
#include "server/bounded_text.h"

extern char** environ;

namespace nimbus::server {

namespace {

// The child's instructions travel in its environment (see the header).
constexpr char kEnvMode[] = "NIMBUS_FILE_CHECK";  // "vdb" or "mesh"
constexpr char kEnvPath[] = "NIMBUS_FILE_CHECK_PATH";
constexpr char kEnvFormat[] = "NIMBUS_FILE_CHECK_FORMAT";
constexpr char kEnvMemory[] = "NIMBUS_FILE_CHECK_MEMORY";
// Grids: where the checker re-writes the float grids it read.
constexpr char kEnvLaundered[] = "NIMBUS_FILE_CHECK_LAUNDERED";
constexpr char kEnvCpu[] = "NIMBUS_FILE_CHECK_CPU";
constexpr char kCheckerArg0[] = "nimbus-file-check";
constexpr int kExitRejected = 3;
// The reader's own words kept in a message; its text can be a gigabyte.
constexpr size_t kMaxReasonBytes = 300;

// ---- child side: runs before main, in a process of its own ----

void Report(absl::string_view reason) {
  reason = reason.substr(0, kMaxReasonBytes);
  while (!reason.empty()) {
    const ssize_t n = ::write(1, reason.data(), reason.size());
    if (n <= 0) return;
    reason.remove_prefix(size_t(n));
  }
}

// At most kMaxReasonBytes of an exception's text, without measuring all of it.
absl::string_view ShortWhat(const char* what) {
  return absl::string_view(what, ::strnlen(what, kMaxReasonBytes));
}

uint64_t EnvNumber(const char* name, uint64_t fallback) {
  const char* v = std::getenv(name);
  uint64_t out = 0;
  return v != nullptr && absl::SimpleAtoi(v, &out) ? out : fallback;
}

void ApplyLimits() {
  const rlim_t memory = EnvNumber(kEnvMemory, uint64_t{2} << 30);
  const rlim_t cpu = EnvNumber(kEnvCpu, 60);
  const rlimit as{memory, memory}, cpu_limit{cpu, cpu + 1}, none{0, 0};
  ::setrlimit(RLIMIT_AS, &as);
  // SIGXCPU at the soft limit, SIGKILL a second later.
  ::setrlimit(RLIMIT_CPU, &cpu_limit);
  ::setrlimit(RLIMIT_CORE, &none);
  // A reader has nothing to write, unless it launders grids (no bigger
  // than its memory: they were all in it).
  const bool writes = std::getenv(kEnvLaundered) != nullptr;
  ::setrlimit(RLIMIT_FSIZE, writes ? &as : &none);
}

// The reading itself is OpenVDB's, in the module (CheckUntrustedVdb).
int CheckVdbChild(const char* path) {
  const char* laundered = std::getenv(kEnvLaundered);
  const absl::Status checked = CheckUntrustedVdb(path, laundered != nullptr ? laundered : "");
  if (checked.ok()) return 0;
  Report(checked.message());
  return kExitRejected;
}

int CheckMeshChild(const char* path) {
  const char* format = std::getenv(kEnvFormat);
  MeshLoadOptions options;
  options.type = MeshFileTypeFromName(format == nullptr ? "" : format);
  options.display_name = "mesh";
  auto mesh = LoadMesh(path, options);
  if (mesh.ok()) return 0;
  absl::string_view msg = mesh.status().message();
  if (absl::ConsumePrefix(&msg, "mesh: ")) {
  }  // the parent names the file
  Report(msg);
  return kExitRejected;
}

int RunChecker(const char* mode) {
  ApplyLimits();
  const char* path = std::getenv(kEnvPath);
  if (path == nullptr) return 2;
  try {
    return absl::string_view(mode) == "vdb" ? CheckVdbChild(path) : CheckMeshChild(path);
  } catch (const std::bad_alloc&) {
    Report("the reader ran out of memory");
  } catch (const std::exception& e) {
    Report(ShortWhat(e.what()));
  } catch (...) {
    Report("the reader failed");
  }
  return kExitRejected;
}

// The checker's entry point: a process started as kCheckerArg0 with
// NIMBUS_FILE_CHECK set never reaches main (both, so a stray variable in an
// operator's shell cannot turn nimbusd into a checker). glibc passes
// main's arguments to constructors. _Exit skips the static destructors of a
// program that never ran.
__attribute__((constructor)) void FileCheckEntry(int argc, char** argv, char**) {
  if (argc < 1 || argv == nullptr || argv[0] == nullptr) return;
  if (std::strcmp(argv[0], kCheckerArg0) != 0) return;
  const char* mode = std::getenv(kEnvMode);
  if (mode != nullptr && *mode != '\0') std::_Exit(RunChecker(mode));
}

// ---- parent side ----

struct ChildOutcome {
  int wait_status = 0;
  bool timed_out = false;
  std::string output;
};

// The parent's environment (shared libraries may need it) without any
// stale checker variables, plus the child's instructions.
std::vector<std::string> ChildEnvironment(const UntrustedFile& file, const SandboxLimits& limits) {
  std::vector<std::string> env;
  for (char** e = environ; e != nullptr && *e != nullptr; ++e)
    if (absl::string_view(*e).substr(0, std::strlen(kEnvMode)) != kEnvMode) env.emplace_back(*e);
  env.push_back(absl::StrCat(kEnvMode, "=", file.kind == UntrustedKind::kVdbGrid ? "vdb" : "mesh"));
  env.push_back(absl::StrCat(kEnvPath, "=", file.path.string()));
  env.push_back(absl::StrCat(kEnvFormat, "=", file.format));
  if (!file.laundered.empty())
    env.push_back(absl::StrCat(kEnvLaundered, "=", file.laundered.string()));
  env.push_back(absl::StrCat(kEnvMemory, "=", limits.memory_bytes));
  env.push_back(absl::StrCat(kEnvCpu, "=", limits.cpu_seconds));
  return env;
}

absl::StatusOr<pid_t> Spawn(const UntrustedFile& file, const SandboxLimits& limits, int out_fd) {
  std::vector<std::string> env = ChildEnvironment(file, limits);
  std::vector<char*> envp;
  for (std::string& e : env) envp.push_back(e.data());
  envp.push_back(nullptr);
  std::string arg0 = kCheckerArg0;
  char* argv[] = {arg0.data(), nullptr};

  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_adddup2(&actions, out_fd, 1);
  // OpenVDB may print; the parent's log is not the place for it.
  posix_spawn_file_actions_addopen(&actions, 2, "/dev/null", O_WRONLY, 0);
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  sigset_t none, all;
  sigemptyset(&none);
  sigfillset(&all);
  sigdelset(&all, SIGKILL);
  sigdelset(&all, SIGSTOP);
  posix_spawnattr_setsigmask(&attr, &none);
  posix_spawnattr_setsigdefault(&attr, &all);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGMASK | POSIX_SPAWN_SETSIGDEF);
  pid_t pid = 0;
  const int rc = posix_spawn(&pid, "/proc/self/exe", &actions, &attr, argv, envp.data());
  posix_spawn_file_actions_destroy(&actions);
  posix_spawnattr_destroy(&attr);
  if (rc != 0)
    return absl::UnavailableError(
        absl::StrCat("cannot start the file checker: ", std::strerror(rc)));
  return pid;
}

// Reads the child's report until it closes its end or the deadline passes.
void ReadReport(int fd, std::chrono::steady_clock::time_point deadline, ChildOutcome& out) {
  char buf[4096];
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      out.timed_out = true;
      return;
    }
    pollfd p{fd, POLLIN, 0};
    const int r = ::poll(&p, 1, int(std::min<int64_t>(left.count(), 1000)));
    if (r < 0 && errno != EINTR) return;
    if (r <= 0) continue;
    const ssize_t n = ::read(fd, buf, sizeof buf);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return;
    if (out.output.size() < 4096) out.output.append(buf, size_t(n));
  }
}

absl::StatusOr<ChildOutcome> RunInChild(const UntrustedFile& file, const SandboxLimits& limits) {
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0)
    return absl::UnavailableError(
        absl::StrCat("cannot start the file checker: ", std::strerror(errno)));
  auto pid = Spawn(file, limits, fds[1]);
  ::close(fds[1]);
  if (!pid.ok()) {
    ::close(fds[0]);
    return pid.status();
  }
  ChildOutcome out;
  ReadReport(fds[0], std::chrono::steady_clock::now() + std::chrono::seconds(limits.wall_seconds),
             out);
  ::close(fds[0]);
  if (out.timed_out) ::kill(*pid, SIGKILL);
  while (::waitpid(*pid, &out.wait_status, 0) < 0 && errno == EINTR) {
  }
  return out;
}

std::string FailureReason(const ChildOutcome& out, const SandboxLimits& limits) {
  if (out.timed_out) return absl::StrCat("reading took longer than ", limits.wall_seconds, " s");
  const int st = out.wait_status;
  if (WIFEXITED(st) && WEXITSTATUS(st) == kExitRejected)
    return BoundText(out.output, kMaxReasonBytes);
  if (WIFSIGNALED(st)) {
    const int sig = WTERMSIG(st);
    if (sig == SIGXCPU || sig == SIGKILL)
      return absl::StrCat("reading used more than ", limits.cpu_seconds, " s of CPU");
    return absl::StrCat("the reader crashed (", strsignal(sig), ")");
  }
  return absl::StrCat("the reader failed (exit status ", WEXITSTATUS(st), ")");
}

}  // namespace

absl::Status CheckUntrustedFile(const UntrustedFile& file, const SandboxLimits& limits) {
  auto out = RunInChild(file, limits);
  if (!out.ok()) return out.status();
  if (!out->timed_out && WIFEXITED(out->wait_status) && WEXITSTATUS(out->wait_status) == 0)
    return absl::OkStatus();
  const char* what =
      file.kind == UntrustedKind::kVdbGrid ? "not a readable VDB file" : "not a readable mesh";
  return absl::InvalidArgumentError(absl::StrCat(what, ": ", FailureReason(*out, limits)));
}

absl::Status CheckStoredAsset(const std::string& sha256, const UntrustedFile& file,
                              const SandboxLimits& limits) {
  static std::mutex mu;
  static std::set<std::string> passed;
  const std::string key =
      absl::StrCat(sha256, file.kind == UntrustedKind::kVdbGrid ? "/vdb/" : "/mesh/", file.format);
  {
    std::lock_guard<std::mutex> lock(mu);
    std::error_code ec;
    const bool copy_kept = file.kind != UntrustedKind::kVdbGrid ||
                           std::filesystem::exists(spec::LaunderedPath(file.path), ec);
    if (passed.count(key) != 0 && copy_kept) return absl::OkStatus();
  }
  UntrustedFile checked = file;
  if (file.kind == UntrustedKind::kVdbGrid) checked.laundered = spec::LaunderedPath(file.path);
  absl::Status st = CheckUntrustedFile(checked, limits);
  if (st.ok()) {
    std::lock_guard<std::mutex> lock(mu);
    passed.insert(key);
  }
  return st;
}

absl::Status CheckSpecAssets(const v1::JobSpec& spec, const std::filesystem::path& asset_dir,
                             bool allow_local_paths, const SandboxLimits& limits) {
  if (!allow_local_paths)
    if (auto st = spec::RefuseAssetPaths(spec); !st.ok()) return st;
  // Every asset ForEachAsset knows: set IFS sources and fractal-field shapes.
  v1::JobSpec copy = spec;  // ForEachAsset visits mutable assets
  absl::Status result;
  spec::ForEachAsset(copy, [&](const std::string& field, v1::Asset& asset) {
    if (!result.ok()) return;
    UntrustedFile file;
    file.kind =
        absl::EndsWith(field, ".mesh.asset") ? UntrustedKind::kMesh : UntrustedKind::kVdbGrid;
    const char* noun = file.kind == UntrustedKind::kMesh ? "mesh asset " : "grid asset ";
    const std::string label = BoundText(asset.label(), 128);
    absl::Status st;
    std::string display;
    if (asset.source_case() == v1::Asset::kSha256) {
      if (asset_dir.empty()) return;
      auto stored = spec::FindStoredAssetInfo(asset_dir, asset.sha256());
      if (!stored.ok()) return;  // the converter names the missing upload
      file.path = stored->path;
      file.format = spec::AssetFormat(label, *stored);
      display = spec::AssetDisplayName(label, EchoId(asset.sha256()));
      st = CheckStoredAsset(asset.sha256(), file, limits);
    } else if (asset.source_case() == v1::Asset::kPath) {
      std::error_code ec;
      if (!std::filesystem::is_regular_file(asset.path(), ec)) return;
      file.path = asset.path();
      file.format = spec::KnownAssetFormat(label.empty() ? asset.path() : label);
      display = BoundText(asset.path(), 256);
      st = CheckUntrustedFile(file, limits);
    } else {
      return;
    }
    if (absl::IsInvalidArgument(st))
      result =
          absl::InvalidArgumentError(absl::StrCat(field, ": ", noun, display, ": ", st.message()));
    else
      result = st;
  });
  return result;
}

}  // namespace nimbus::server
