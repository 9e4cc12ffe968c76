// nimbus: the command-line client. Without --server it starts an embedded
// in-process server on a local data folder, so it works with no setup.
#include <google/protobuf/util/json_util.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "client/flame_import.h"
#include "client/nimbus_client.h"
#include "client/output_names.h"
#include "client/preview_files.h"
#include "core/base/heap_tuning.h"
#include "core/base/status_macros.h"
#include "proto/asset_paths.h"
#include "proto/spec_convert.h"
#include "proto/spec_io.h"
#include "server/memory_admission.h"
#include "server/server.h"

namespace {

using nimbus::client::NimbusClient;
namespace v1 = nimbus::v1;

// Exit codes: 0 success, 1 job failed or was cancelled, 2 bad input or
// bad data (a download whose size or sha256 does not match), 3 server
// unreachable or internal error.
constexpr int kJobFailed = 1, kBadInput = 2, kServerError = 3;

int ExitFor(const absl::Status& s) {
  std::cerr << "nimbus: " << s.message() << " [" << absl::StatusCodeToString(s.code()) << "]\n";
  switch (s.code()) {
    case absl::StatusCode::kInvalidArgument:
    case absl::StatusCode::kNotFound:
    case absl::StatusCode::kFailedPrecondition:
    case absl::StatusCode::kResourceExhausted:
    case absl::StatusCode::kOutOfRange:
    case absl::StatusCode::kUnauthenticated:
    case absl::StatusCode::kPermissionDenied:
    case absl::StatusCode::kDataLoss: return kBadInput;
    default: return kServerError;
  }
}

std::filesystem::path DefaultDataDir() {
  if (const char* d = std::getenv("NIMBUS_DATA_DIR")) return d;
  if (const char* x = std::getenv("XDG_CACHE_HOME")) return std::filesystem::path(x) / "nimbus";
  if (const char* h = std::getenv("HOME")) return std::filesystem::path(h) / ".cache" / "nimbus";
  return ".nimbus";
}

struct Connection {
  // A private data dir for this run only, removed after the server stops
  // (first member: destroyed last).
  std::shared_ptr<const std::filesystem::path> scratch;
  std::unique_ptr<nimbus::server::NimbusServer> embedded;
  std::unique_ptr<NimbusClient> client;
};

struct GlobalOptions {
  std::string server;
  nimbus::client::ConnectOptions connect;
  std::string data_dir;
  int threads = 0;
  bool verbose = false;
};

// A fresh folder under the system's temp dir, removed with the last copy
// of the pointer.
absl::StatusOr<std::shared_ptr<const std::filesystem::path>> ScratchDataDir() {
  std::string pattern = (std::filesystem::temp_directory_path() / "nimbus-run-XXXXXX").string();
  if (::mkdtemp(pattern.data()) == nullptr)
    return absl::InternalError(absl::StrCat("cannot create ", pattern, ": ", std::strerror(errno)));
  return std::shared_ptr<const std::filesystem::path>(
      new std::filesystem::path(pattern), [](const std::filesystem::path* p) {
        std::error_code ec;
        std::filesystem::remove_all(*p, ec);
        delete p;
      });
}

// Without --server, an embedded server on the data dir. With
// `private_if_busy` (commands that fetch their result before they exit), a
// default data dir another process serves gives way to a private one: two
// renders in two terminals both run instead of the second failing.
absl::StatusOr<Connection> Connect(const GlobalOptions& g, bool private_if_busy = false) {
  Connection c;
  if (!g.server.empty()) {
    NIMBUS_ASSIGN_OR_RETURN(c.client, NimbusClient::Connect(g.server, g.connect));
    if (auto s = c.client->WaitForReady(10); !s.ok())
      return absl::UnavailableError(absl::StrCat("cannot reach nimbusd at ", g.server));
    return c;
  }
  nimbus::server::ServerOptions o;
  o.listen = "";
  o.data_dir = g.data_dir.empty() ? DefaultDataDir() : std::filesystem::path(g.data_dir);
  o.threads_per_job = g.threads;
  // One user, one job: no reserve to keep for others. A full disk still
  // fails the render with "disk full while writing the result".
  o.min_free_disk_mib = 0;
  // When the command ends, nothing of this process is left to serve: open
  // streams are cancelled at once instead of drained.
  o.drain_ms = 0;
  auto server = nimbus::server::NimbusServer::Start(o);
  if (!server.ok() && absl::IsFailedPrecondition(server.status()) && private_if_busy &&
      g.data_dir.empty()) {
    NIMBUS_ASSIGN_OR_RETURN(c.scratch, ScratchDataDir());
    std::cerr << "note: " << server.status().message() << "\nnote: this render uses a private "
              << "data dir instead (" << c.scratch->string() << "), removed when it ends\n";
    o.data_dir = *c.scratch;
    server = nimbus::server::NimbusServer::Start(o);
  }
  if (!server.ok()) return server.status();
  c.embedded = std::move(*server);
  c.client = std::make_unique<NimbusClient>(c.embedded->InProcessChannel());
  return c;
}

// A job's main result to `path`: an embedded server's store hands it over
// directly (the same hash check, no gRPC stream); a remote one streams it.
absl::Status FetchMain(const Connection& c, const std::string& job_id,
                       const std::filesystem::path& path) {
  if (c.embedded) return c.embedded->ExportResult(job_id, path);
  return c.client->Fetch(job_id, path);
}

std::string Human(double v) {
  const char* units[] = {"", "K", "M", "G", "T"};
  int u = 0;
  while (v >= 1000 && u < 4) v /= 1000, ++u;
  return absl::StrFormat("%.1f%s", v, units[u]);
}

std::string Duration(double s) {
  if (s <= 0) return "--";
  const int64_t t = int64_t(s + 0.5);
  if (t >= 3600) return absl::StrFormat("%dh%02dm", t / 3600, (t / 60) % 60);
  if (t >= 60) return absl::StrFormat("%dm%02ds", t / 60, t % 60);
  return absl::StrFormat("%ds", t);
}

const char* StateName(v1::JobState s) {
  switch (s) {
    case v1::JOB_STATE_QUEUED: return "queued";
    case v1::JOB_STATE_RUNNING: return "running";
    case v1::JOB_STATE_SUCCEEDED: return "succeeded";
    case v1::JOB_STATE_FAILED: return "failed";
    case v1::JOB_STATE_CANCELLED: return "cancelled";
    default: return "unknown";
  }
}

// The phase a running job is in, as the progress line names it.
std::string PhaseLabel(const v1::Job& job) {
  if (job.state() != v1::JOB_STATE_RUNNING) return StateName(job.state());
  switch (job.progress().phase()) {
    case v1::PROGRESS_PHASE_PREPARING: return "preparing";
    case v1::PROGRESS_PHASE_ITERATING: return "iterating";
    case v1::PROGRESS_PHASE_WRITING: return "writing";
    default: return "running";
  }
}

// Draws a progress bar on a terminal, or a line per 10% otherwise. Each
// phase counts its own units, so the bar restarts when the phase changes.
class ProgressView {
 public:
  ProgressView() : tty_(::isatty(2)) {}
  void Update(const v1::Job& job) {
    const auto& p = job.progress();
    const double f = p.total() ? double(p.done()) / double(p.total()) : 0;
    const std::string label = PhaseLabel(job);
    const std::string unit = p.unit().empty() ? "it" : p.unit();
    if (tty_) {
      const int width = 30, filled = int(f * width);
      std::string bar(filled, '#');
      bar.resize(width, '.');
      std::fprintf(stderr, "\r%-9s [%s] %5.1f%%  %s %s/s  ETA %s   ", label.c_str(), bar.c_str(),
                   100 * f, Human(p.rate()).c_str(), unit.c_str(),
                   Duration(p.eta_seconds()).c_str());
      std::fflush(stderr);
      drawn_ = true;
    } else if (int(f * 10) != last_decile_ || label != last_label_) {
      last_decile_ = int(f * 10);
      last_label_ = label;
      std::fprintf(stderr, "%s %5.1f%%  %s %s/s  ETA %s\n", label.c_str(), 100 * f,
                   Human(p.rate()).c_str(), unit.c_str(), Duration(p.eta_seconds()).c_str());
    }
  }
  void Done() {
    if (drawn_) std::fprintf(stderr, "\n");
    drawn_ = false;
  }
  // A line of its own above the bar (which the next update redraws).
  void Note(const std::string& line) {
    if (drawn_) std::fprintf(stderr, "\r\033[K");
    std::fprintf(stderr, "%s\n", line.c_str());
    drawn_ = false;
  }

 private:
  bool tty_;
  bool drawn_ = false;
  int last_decile_ = -1;
  std::string last_label_;
};

struct WatchArgs {
  std::string previews;
  uint32_t preview_resolution = 64;
  double preview_interval = 1.0;
  bool events = false;
};

// "2026-11-29T03:04:05Z" (UTC, seconds).
std::string UtcTime(const google::protobuf::Timestamp& t) {
  const std::time_t secs = static_cast<std::time_t>(t.seconds());
  std::tm tm{};
  char text[32] = "-";
  if (secs > 0 && ::gmtime_r(&secs, &tm) != nullptr)
    std::strftime(text, sizeof(text), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return text;
}

// One event as `nimbus events` prints it: seq, time, kind, the non-empty
// fields in name order (so the output is stable).
std::string EventLine(const v1::JobEvent& e) {
  std::map<std::string, std::string> fields(e.fields().begin(), e.fields().end());
  std::string text;
  for (const auto& [name, value] : fields)
    if (!value.empty()) absl::StrAppend(&text, " ", name, "=", value);
  return absl::StrFormat("%5d %s %-16s%s", e.seq(), UtcTime(e.time()), e.kind(), text);
}

// Watches a job to its end, saving previews; returns its final view.
absl::StatusOr<v1::Job> WatchJob(
    NimbusClient& client, const std::string& id, const WatchArgs& w, bool quiet,
    const std::function<void(const v1::Job&)>& on_job = nullptr) {
  nimbus::client::WatchOptions o;
  if (!w.previews.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(w.previews, ec);
    if (ec) return absl::InvalidArgumentError(absl::StrCat("--previews ", w.previews, ": ", ec.message()));
    o.preview_resolution = w.preview_resolution;
    o.preview_interval_seconds = w.preview_interval;
  }
  o.events = w.events;
  ProgressView view;
  nimbus::client::PreviewSaver saver(w.previews);
  absl::Status save_error;
  auto job = client.Watch(id, o, [&](const v1::WatchJobResponse& r) {
    for (const v1::JobEvent& e : r.events()) view.Note(EventLine(e));
    if (!quiet) view.Update(r.job());
    if (on_job) on_job(r.job());
    if (r.has_preview() && !w.previews.empty() && save_error.ok())
      save_error = saver.Save(r.job().name(), r.preview()).status();
  });
  if (!quiet) view.Done();
  if (job.ok() && !save_error.ok()) return save_error;
  if (job.ok() && saver.saved() > 0)
    std::cerr << "saved " << saver.saved() << " previews in " << w.previews << "\n";
  return job;
}

// Downloads a job's further files (book pages) as they are listed, named
// after the output: NAME.0007.vdb from the server becomes OUT.0007.vdb next
// to -o, or in --frames.
class FrameFetcher {
 public:
  FrameFetcher(NimbusClient& client, std::string job_id, std::filesystem::path folder,
               std::string stem)
      : client_(client), job_id_(std::move(job_id)), folder_(std::move(folder)),
        stem_(std::move(stem)) {}

  absl::Status FetchNew(const v1::Job& job) {
    for (const v1::ResultFile& f : job.result().files()) {
      if (done_.count(f.file_name())) continue;
      const std::filesystem::path out = folder_ / LocalName(job.name(), f.file_name());
      if (auto s = client_.Fetch(job_id_, out, f.file_name()); !s.ok()) return s;
      done_.insert(f.file_name());
      last_ = out;
    }
    return absl::OkStatus();
  }
  size_t count() const { return done_.size(); }
  const std::filesystem::path& last() const { return last_; }

 private:
  std::string LocalName(const std::string& job_name, const std::string& file) const {
    if (file.starts_with(job_name + ".")) return stem_ + file.substr(job_name.size());
    return file;
  }
  NimbusClient& client_;
  std::string job_id_;
  std::filesystem::path folder_;
  std::string stem_;
  std::set<std::string> done_;
  std::filesystem::path last_;
};

int Finished(const v1::Job& job) {
  for (const auto& w : job.warnings()) std::cerr << "warning: " << w << "\n";
  if (job.state() == v1::JOB_STATE_SUCCEEDED) return 0;
  std::cerr << "nimbus: job " << job.id() << " " << StateName(job.state())
            << (job.error().empty() ? "" : ": " + job.error()) << "\n";
  return kJobFailed;
}

// Everything the command line sets; each subcommand reads its part.
struct Options {
  GlobalOptions global;
  std::string spec_path, out_path, job_id;
  std::string frames_dir;    // render
  std::string fetch_file;    // fetch
  std::string state_filter;  // jobs
  std::string health_service;  // health
  int limit = 20;            // jobs
  WatchArgs watch;           // render, watch
  int body = 0;              // poke
  std::string impulse, drag;
  double drag_stiffness = 0;
  uint32_t drag_frames = 0;
  nimbus::client::FlameImportOptions flame;  // import-flame
  bool no_cache = false;     // render, submit, explore
  struct {
    std::string name = "explore";
    int32_t count = 0, size = 0, dim = 0;
    uint64_t seed = 0;
    double threshold = 0;
    std::string maps, measure;
    std::vector<std::string> variations;
    const CLI::App* command = nullptr;  // tells which flags were given
  } explore;
  uint32_t shards = 0;       // render, submit
  std::optional<int> priority;  // render, submit (--priority); priority N
};

std::atomic<bool> g_interrupted{false};
void OnSigint(int) { g_interrupted = true; }

// While alive, Ctrl-C cancels the job rather than leaving it queued behind.
// Stop() (or the destructor) ends the watch for it at once: the command
// does not wait out a polling interval before it exits.
class CancelOnInterrupt {
 public:
  CancelOnInterrupt(NimbusClient& client, std::string job_id) {
    std::signal(SIGINT, OnSigint);
    thread_ = std::thread([this, &client, id = std::move(job_id)] {
      std::unique_lock<std::mutex> lock(mu_);
      // A signal handler may not notify, so the flag is polled.
      while (!cv_.wait_for(lock, std::chrono::milliseconds(50), [this] { return finished_; })) {
        if (g_interrupted) {
          lock.unlock();
          (void)client.Cancel(id);
          return;
        }
      }
    });
  }
  ~CancelOnInterrupt() {
    Stop();
    thread_.join();
  }
  void Stop() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      finished_ = true;
    }
    cv_.notify_all();
  }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  bool finished_ = false;
  std::thread thread_;
};

// `nimbus validate`'s lines for each kind of job plan, after its name; one
// overload per kind, so a new kind without its summary does not compile.
struct KindSummary {
  const nimbus::JobPlan& plan;
  const v1::JobSpec& spec;
  std::string peak;  // the "peak memory" line

  void Grid() const {
    const auto r = plan.frame.resolution;
    std::cout << "  grid: " << r.x << " x " << r.y << " x " << r.z << "\n";
  }
  void Hash() const { std::cout << "  spec sha256: " << nimbus::spec::SpecHash(spec) << "\n"; }
  void PointRun(const nimbus::ChaosGameParams& run) const {
    Grid();
    std::cout << "  maps: " << run.ifs.maps.size() << "\n";
    for (size_t i = 0; i < run.ifs.maps.size(); ++i)
      std::cout << absl::StrFormat("    [%d] p=%.4f contraction=%.4f %s\n", i,
                                   run.ifs.probabilities[i], plan.contraction_factors[i],
                                   run.ifs.maps[i].name);
    std::cout << "  iterations: " << run.iterations << "\n" << peak;
    Hash();
  }
  void operator()(const nimbus::ChaosGamePlan& p) const { PointRun(p.params); }
  void operator()(const nimbus::IfsMatrixPlan& p) const { PointRun(p.run); }
  void operator()(const nimbus::SetIfsPlan& p) const {
    static const char* kKinds[] = {"median", "rotated median", "constant", "point"};
    Grid();
    std::cout << "  set maps: " << p.maps.size() << "\n";
    for (size_t i = 0; i < p.maps.size(); ++i)
      std::cout << absl::StrFormat("    [%s] p=%.4f %s\n", p.labels[i], p.probabilities[i],
                                   kKinds[int(p.maps[i].kind)]);
    if (p.book)
      std::cout << "  book: depth " << p.depth << ", " << p.pages << " pages\n";
    else
      std::cout << "  set iterations: " << p.iterations << " after " << p.warmup << " warm-up\n";
    std::cout << peak;
  }
  void operator()(const nimbus::FractalFieldPlan& f) const {
    static const char* kInterp[] = {"n-linear", "pseudo n-cubic", "quintic", "cubic"};
    Grid();
    std::cout << "  field: " << f.field.dims << "D, " << f.field.meshes.size() << " meshes, "
              << kInterp[int(f.field.interpolation)] << ", "
              << (f.output == nimbus::FieldOutputKind::kTerrain ? "terrain" : "density")
              << (f.shape ? ", shaped" : "") << "\n";
    for (size_t k = 0; k < f.field.meshes.size(); ++k)
      std::cout << absl::StrFormat("    [%d] cell=%.6g weight=%.6g\n", k,
                                   f.field.meshes[k].cell[0], f.field.meshes[k].weight);
    if (f.animation.frames > 0)
      std::cout << "  frames: " << f.animation.frames << (f.animation.loop ? " (loop)" : "")
                << "\n";
    std::cout << peak;
    Hash();
  }
  void operator()(const nimbus::JellyPlan& p) const {
    Grid();
    std::cout << "  bodies: " << p.sim.bodies.size() << ", springs: " << p.sim.springs.size()
              << "\n"
              << absl::StrFormat("  frames: %u at %g fps, %u substeps (dt %g s)\n", p.frames,
                                 p.fps, p.substeps, p.sim.dt)
              << peak;
  }
  void operator()(const nimbus::ExplorePlan& e) const {
    const nimbus::ExploreParams& p = e.params;
    const bool sv = p.measure == nimbus::ContractionMeasure::kSingularValue;
    std::cout << absl::StrFormat("  explore: %d candidates, %dD IFS of %d-%d maps, seed %d\n",
                                 p.count, p.draw.dimensions, p.draw.min_maps, p.draw.max_maps,
                                 p.seed)
              << absl::StrFormat("  keep: %s < %g, at most %d random IFS\n",
                                 sv ? "largest singular value" : "sum of |det|", p.threshold,
                                 p.max_attempts)
              << absl::StrFormat("  thumbnails: %d px, %d iterations each\n", p.thumbnail_size,
                                 p.thumbnail_iterations)
              << peak;
    Hash();
  }
};

// The one place that reads a converted spec (the job plan): `nimbus
// validate`'s summary. Memory is priced as for a two-thread run.
int PrintValidation(const std::string& spec_path, const v1::JobSpec& spec) {
  const nimbus::spec::Limits limits;
  auto plan = nimbus::spec::ConvertSpec(spec, limits);
  if (!plan.ok()) return ExitFor(plan.status());
  auto memory = nimbus::server::AdmitMemory(*plan, limits, 2);
  if (!memory.ok()) return ExitFor(memory.status());
  std::cout << spec_path << ": ok\n"
            << "  name: " << plan->name << "\n";
  const std::string peak = absl::StrFormat("  peak memory (estimate): %.1f MiB\n",
                                           double(memory->estimated_bytes) / (1 << 20));
  std::visit(KindSummary{*plan, spec, peak}, plan->kind);
  for (const auto& w : plan->warnings) std::cout << "  warning: " << w << "\n";
  return 0;
}

int RunValidate(const Options& o) {
  auto spec = nimbus::spec::LoadSpecFile(o.spec_path);
  if (!spec.ok()) return ExitFor(spec.status());
  nimbus::spec::ResolveAssetPaths(*spec, std::filesystem::path(o.spec_path).parent_path());
  return PrintValidation(o.spec_path, *spec);
}

// Converts a flam3 genome into a spec file (docs/flame_import.md), checked
// by the same converter the server uses before it is written.
int RunImportFlame(const Options& o) {
  std::ifstream in(o.spec_path, std::ios::binary);
  if (!in) return ExitFor(absl::NotFoundError(absl::StrCat("cannot read ", o.spec_path)));
  std::string xml(size_t{64} << 20, '\0');
  in.read(xml.data(), std::streamsize(xml.size()));
  if (in.gcount() == std::streamsize(xml.size()))
    return ExitFor(absl::InvalidArgumentError(o.spec_path + ": larger than 64 MiB"));
  xml.resize(size_t(in.gcount()));
  auto got = nimbus::client::ImportFlame(xml, o.flame);
  if (!got.ok())
    return ExitFor(absl::Status(got.status().code(),
                                o.spec_path + ": " + std::string(got.status().message())));
  for (const std::string& w : got->warnings) std::cerr << "nimbus: warning: " << w << "\n";
  auto plan = nimbus::spec::ConvertSpec(got->spec, nimbus::spec::Limits{});
  if (!plan.ok()) return ExitFor(plan.status());
  const std::string json = nimbus::spec::SpecToJson(got->spec);
  if (o.out_path.empty() || o.out_path == "-") {
    std::cout << json;
    return 0;
  }
  std::ofstream(o.out_path) << json;
  std::cerr << "nimbus: wrote " << o.out_path << " (genome '" << got->spec.name() << "', "
            << got->spec.chaos_game().ifs().maps_size() << " maps)\n";
  return 0;
}

// A connection plus a loaded spec whose local mesh and grid files are
// already on the server: the common start of render and submit.
struct SpecSession {
  Connection conn;
  v1::JobSpec spec;
};

// `check` sees the spec before a server is reached.
absl::StatusOr<SpecSession> OpenWithSpec(
    const Options& o, bool private_if_busy,
    const std::function<absl::Status(const v1::JobSpec&)>& check = nullptr) {
  SpecSession s;
  NIMBUS_ASSIGN_OR_RETURN(s.spec, nimbus::spec::LoadSpecFile(o.spec_path));
  // Command-line overrides of the spec (docs/result_cache.md, docs/sharding.md).
  if (o.no_cache) s.spec.set_no_cache(true);
  if (o.shards > 0) s.spec.set_shards(o.shards);
  if (check) NIMBUS_RETURN_IF_ERROR(check(s.spec));
  NIMBUS_ASSIGN_OR_RETURN(s.conn, Connect(o.global, private_if_busy));
  NIMBUS_RETURN_IF_ERROR(
      s.conn.client->UploadSpecAssets(s.spec, std::filesystem::path(o.spec_path).parent_path()));
  return s;
}

// Creates -o's folder (best effort) and --frames; returns where further
// result files go.
absl::StatusOr<std::filesystem::path> PrepareOutputs(const Options& o) {
  const std::filesystem::path out(o.out_path);
  if (out.has_parent_path()) {
    std::error_code ec;
    std::filesystem::create_directories(out.parent_path(), ec);
  }
  if (o.frames_dir.empty()) return out.parent_path();
  std::error_code ec;
  std::filesystem::create_directories(o.frames_dir, ec);
  if (ec)
    return absl::InvalidArgumentError(absl::StrCat("--frames ", o.frames_dir, ": ", ec.message()));
  return std::filesystem::path(o.frames_dir);
}

// "wrote x.png" for one further file, "wrote 12 further files, the last
// x.0012.vdb" for several.
std::string FurtherFilesLine(const FrameFetcher& files) {
  if (files.count() == 1) return absl::StrCat("wrote ", files.last().string(), "\n");
  return absl::StrFormat("wrote %d further files, the last %s\n", files.count(),
                         files.last().string());
}

int RunRender(const Options& o) {
  std::filesystem::path main_path;
  auto session = OpenWithSpec(o, /*private_if_busy=*/true, [&](const v1::JobSpec& spec) {
    NIMBUS_ASSIGN_OR_RETURN(main_path, nimbus::client::MainOutputPath(o.out_path, spec));
    return absl::OkStatus();
  });
  if (!session.ok()) return ExitFor(session.status());
  NimbusClient& client = *session->conn.client;
  auto job = client.Submit(session->spec, "", o.priority);
  if (!job.ok()) return ExitFor(job.status());
  std::cerr << "job " << job->id() << " queued"
            << (session->conn.embedded ? " (embedded server)" : " on " + o.global.server) << "\n";
  CancelOnInterrupt canceller(client, job->id());
  auto folder = PrepareOutputs(o);
  if (!folder.ok()) return ExitFor(folder.status());
  // Book pages are downloaded while later ones are still being made. A
  // failure here is retried from the final list (downloads resume).
  FrameFetcher frames(client, job->id(), *folder,
                      std::filesystem::path(o.out_path).stem().string());
  auto final_job = WatchJob(client, job->id(), o.watch, false, [&](const v1::Job& j) {
    if (j.state() == v1::JOB_STATE_RUNNING) (void)frames.FetchNew(j);
  });
  canceller.Stop();
  if (!final_job.ok()) return ExitFor(final_job.status());
  if (int rc = Finished(*final_job); rc != 0) return rc;
  // The final list carries every file with its committed hash.
  if (auto full = client.Get(job->id()); full.ok())
    if (auto s = frames.FetchNew(*full); !s.ok()) return ExitFor(s);
  if (auto s = FetchMain(session->conn, job->id(), main_path); !s.ok()) return ExitFor(s);
  std::cerr << absl::StrFormat("wrote %s (%s bytes, sha256 %s)\n", main_path.string(),
                               Human(double(final_job->result().size_bytes())),
                               final_job->result().sha256());
  if (frames.count() > 0) std::cerr << FurtherFilesLine(frames);
  return 0;
}

// "a-b" or "a" as a map-count range; INVALID_ARGUMENT naming --maps.
absl::Status ParseMapRange(const std::string& text, v1::Explore& e) {
  if (text.empty()) return absl::OkStatus();
  const std::vector<std::string> parts = absl::StrSplit(text, '-');
  int lo = 0, hi = 0;
  if (parts.size() > 2 || !absl::SimpleAtoi(parts[0], &lo) ||
      !absl::SimpleAtoi(parts.back(), &hi))
    return absl::InvalidArgumentError(
        absl::StrCat("--maps: give a count or a range a-b, got \"", text, "\""));
  if (lo <= 0 || hi <= 0)
    return absl::InvalidArgumentError(
        absl::StrCat("--maps: counts must be positive, got \"", text, "\""));
  e.set_min_maps(lo);
  e.set_max_maps(hi);
  return absl::OkStatus();
}

// The explore spec of `nimbus explore`: a spec file's, or one built from
// the flags (flags override the file's fields they name).
absl::StatusOr<v1::JobSpec> ExploreSpec(const Options& o, const CLI::App& cmd) {
  v1::JobSpec spec;
  if (!o.spec_path.empty()) {
    NIMBUS_ASSIGN_OR_RETURN(spec, nimbus::spec::LoadSpecFile(o.spec_path));
    if (!spec.has_explore())
      return absl::InvalidArgumentError(o.spec_path + ": not an explore spec (no \"explore\")");
  } else {
    spec.set_name(o.explore.name);
  }
  if (cmd.count("--name")) spec.set_name(o.explore.name);
  v1::Explore& e = *spec.mutable_explore();
  if (cmd.count("--count")) e.set_count(o.explore.count);
  if (cmd.count("--seed")) e.set_seed(o.explore.seed);
  if (cmd.count("--size")) e.set_thumbnail_size(o.explore.size);
  if (cmd.count("--threshold")) e.set_threshold(o.explore.threshold);
  if (cmd.count("--dim")) e.set_dimensions(o.explore.dim);
  NIMBUS_RETURN_IF_ERROR(ParseMapRange(o.explore.maps, e));
  if (!o.explore.measure.empty()) {
    if (o.explore.measure == "sv") {
      e.set_measure(v1::CONTRACTION_MEASURE_SINGULAR_VALUE);
    } else if (o.explore.measure == "det") {
      e.set_measure(v1::CONTRACTION_MEASURE_DETERMINANT);
    } else {
      return absl::InvalidArgumentError("--measure: sv or det, got " + o.explore.measure);
    }
  }
  if (!o.explore.variations.empty()) {
    e.clear_variations();
    for (const std::string& v : o.explore.variations) e.add_variations(v);
  }
  if (o.no_cache) spec.set_no_cache(true);
  return spec;
}

// Explores random IFS (docs/explore.md): submits the spec, shows progress,
// saves the contact sheet as DIR/NAME.png and the candidates' specs as
// DIR/NAME.0001.json, ...
int RunExplore(const Options& o) {
  auto spec = ExploreSpec(o, *o.explore.command);
  if (!spec.ok()) return ExitFor(spec.status());
  // Checked here too, so a bad flag fails before a server starts.
  if (auto plan = nimbus::spec::ConvertSpec(*spec, nimbus::spec::Limits{}); !plan.ok())
    return ExitFor(plan.status());
  auto conn = Connect(o.global, /*private_if_busy=*/true);
  if (!conn.ok()) return ExitFor(conn.status());
  NimbusClient& client = *conn->client;
  auto job = client.Submit(*spec);
  if (!job.ok()) return ExitFor(job.status());
  std::cerr << "job " << job->id() << " queued"
            << (conn->embedded ? " (embedded server)" : " on " + o.global.server) << "\n";
  CancelOnInterrupt canceller(client, job->id());
  const std::filesystem::path dir(o.out_path.empty() ? "." : o.out_path);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return ExitFor(absl::InvalidArgumentError(absl::StrCat("-o ", dir.string(), ": ",
                                                                 ec.message())));
  const std::string name = spec->name().empty() ? "nimbus" : spec->name();
  auto final_job = WatchJob(client, job->id(), o.watch, false);
  canceller.Stop();
  if (!final_job.ok()) return ExitFor(final_job.status());
  if (int rc = Finished(*final_job); rc != 0) return rc;
  FrameFetcher files(client, job->id(), dir, name);
  auto full = client.Get(job->id());
  if (!full.ok()) return ExitFor(full.status());
  if (auto s = files.FetchNew(*full); !s.ok()) return ExitFor(s);
  const std::filesystem::path sheet = dir / (name + ".png");
  if (auto s = FetchMain(*conn, job->id(), sheet); !s.ok()) return ExitFor(s);
  std::cerr << absl::StrFormat("wrote %s and %d candidate specs (%s.0001.json ...) in %s\n",
                               sheet.string(), files.count(), name, dir.string());
  return 0;
}

int RunSubmit(const Options& o) {
  auto session = OpenWithSpec(o, /*private_if_busy=*/false);
  if (!session.ok()) return ExitFor(session.status());
  auto job = session->conn.client->Submit(session->spec, "", o.priority);
  if (!job.ok()) return ExitFor(job.status());
  std::cout << job->id() << "\n";
  if (session->conn.embedded)
    std::cerr << "note: the embedded server runs jobs only while a nimbus command runs; "
                 "`nimbus watch "
              << job->id() << "` runs it to the end\n";
  return 0;
}

int RunWatch(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto job = WatchJob(*conn->client, o.job_id, o.watch, false);
  if (!job.ok()) return ExitFor(job.status());
  return Finished(*job);
}

int RunFetch(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  std::string file_name = o.fetch_file;
  if (file_name.empty()) {
    auto job = conn->client->Get(o.job_id);
    if (!job.ok()) return ExitFor(job.status());
    file_name = job->result().file_name();
  }
  if (auto s = nimbus::client::CheckOutputExtension(o.out_path, file_name); !s.ok())
    return ExitFor(s);
  const absl::Status s = o.fetch_file.empty()
                             ? FetchMain(*conn, o.job_id, o.out_path)
                             : conn->client->Fetch(o.job_id, o.out_path, o.fetch_file);
  if (!s.ok()) return ExitFor(s);
  std::cerr << "wrote " << o.out_path << "\n";
  return 0;
}

int RunGet(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto job = conn->client->Get(o.job_id);
  if (!job.ok()) return ExitFor(job.status());
  std::string json;
  google::protobuf::util::JsonPrintOptions po;
  po.add_whitespace = true;
  po.preserve_proto_field_names = true;
  (void)google::protobuf::util::MessageToJsonString(*job, &json, po);
  std::cout << json;
  return 0;
}

// The server's grpc.health.v1 status: prints it, exits 0 only for SERVING
// (a container or orchestrator probe).
int RunHealth(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto status = conn->client->Health(o.health_service, 5);
  if (!status.ok()) return ExitFor(status.status());
  static const char* const kNames[] = {"UNKNOWN", "SERVING", "NOT_SERVING", "SERVICE_UNKNOWN"};
  std::cout << (*status >= 0 && *status < 4 ? kNames[*status] : "UNRECOGNISED") << "\n";
  return *status == 1 ? 0 : kServerError;
}

int RunJobs(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  v1::ListJobsRequest req;
  req.set_page_size(o.limit);
  if (!o.state_filter.empty()) {
    v1::JobState st;
    if (!v1::JobState_Parse("JOB_STATE_" + absl::AsciiStrToUpper(o.state_filter), &st))
      return ExitFor(absl::InvalidArgumentError("--state: unknown state " + o.state_filter));
    req.set_state(st);
  }
  auto list = conn->client->List(req);
  if (!list.ok()) return ExitFor(list.status());
  // WORKER: who holds a running job ("REPLICA/wN"), so an operator sees
  // which replica runs what.
  std::cout << absl::StrFormat("%-20s %-10s %7s %-24s %-20s %s\n", "ID", "STATE", "DONE", "NAME",
                               "WORKER", "ERROR");
  for (const auto& j : list->jobs()) {
    const double f = j.progress().total() ? 100.0 * j.progress().done() / j.progress().total() : 0;
    std::cout << absl::StrFormat("%-20s %-10s %6.1f%% %-24s %-20s %s\n", j.id(),
                                 StateName(j.state()), f, j.name(),
                                 j.worker().empty() ? "-" : j.worker(), j.error());
  }
  return 0;
}

int RunPin(const Options& o, bool pinned) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto job = conn->client->Pin(o.job_id, pinned);
  if (!job.ok()) return ExitFor(job.status());
  std::cout << job->id() << (job->pinned() ? " pinned" : " unpinned") << "\n";
  return 0;
}

int RunPriority(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto job = conn->client->SetPriority(o.job_id, *o.priority);
  if (!job.ok()) return ExitFor(job.status());
  std::cout << job->id() << " priority " << job->priority() << "\n";
  return 0;
}

int RunRetry(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto job = conn->client->Retry(o.job_id);
  if (!job.ok()) return ExitFor(job.status());
  std::cout << job->id() << "\n";
  return 0;
}

int RunWorkers(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto list = conn->client->ListWorkers();
  if (!list.ok()) return ExitFor(list.status());
  std::cout << absl::StrFormat("%-24s %-6s %-20s %-8s %5s %7s %7s %-20s %s\n", "REPLICA", "STATE",
                               "HOST", "VERSION", "SLOTS", "THREADS", "RUNNING", "LAST HEARTBEAT",
                               "STARTED");
  for (const auto& w : list->workers())
    std::cout << absl::StrFormat("%-24s %-6s %-20s %-8s %5d %7d %7d %-20s %s\n", w.replica_id(),
                                 w.lost() ? "lost" : "alive", w.host(), w.version(),
                                 w.worker_slots(), w.threads_per_job(), w.jobs_running(),
                                 UtcTime(w.last_heartbeat()), UtcTime(w.start_time()));
  return 0;
}

int RunEvents(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  int64_t after = 0;
  do {
    auto page = conn->client->GetJobEvents(o.job_id, after, 500);
    if (!page.ok()) return ExitFor(page.status());
    if (after == 0 && page->dropped() > 0)
      std::cout << "(" << page->dropped() << " older events dropped)\n";
    for (const auto& e : page->events()) std::cout << EventLine(e) << "\n";
    after = page->next_after_seq();
  } while (after != 0);
  return 0;
}

int RunDelete(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto freed = conn->client->Delete(o.job_id);
  if (!freed.ok()) return ExitFor(freed.status());
  std::cout << o.job_id << " deleted (" << *freed << " bytes of results freed)\n";
  return 0;
}

int RunCancel(const Options& o) {
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto job = conn->client->Cancel(o.job_id);
  if (!job.ok()) return ExitFor(job.status());
  std::cout << job->id() << " " << StateName(job->state()) << "\n";
  return 0;
}

// "x,y,z" as a Vec3; INVALID_ARGUMENT naming `flag` otherwise.
absl::StatusOr<v1::Vec3> ParseVec3(const std::string& text, const std::string& flag) {
  const std::vector<std::string> parts = absl::StrSplit(text, ',');
  double xyz[3];
  if (parts.size() != 3 || !absl::SimpleAtod(parts[0], &xyz[0]) ||
      !absl::SimpleAtod(parts[1], &xyz[1]) || !absl::SimpleAtod(parts[2], &xyz[2]))
    return absl::InvalidArgumentError(
        absl::StrCat(flag, ": give three numbers x,y,z, got \"", text, "\""));
  v1::Vec3 v;
  v.set_x(xyz[0]);
  v.set_y(xyz[1]);
  v.set_z(xyz[2]);
  return v;
}

int RunPoke(const Options& o) {
  if (o.impulse.empty() == o.drag.empty())
    return ExitFor(absl::InvalidArgumentError("poke: give exactly one of --impulse or --drag"));
  v1::PokeJobRequest req;
  req.set_job_id(o.job_id);
  v1::JellyPush& push = *req.mutable_push();
  push.set_body(o.body);
  const bool drag = !o.drag.empty();
  auto v = ParseVec3(drag ? o.drag : o.impulse, drag ? "--drag" : "--impulse");
  if (!v.ok()) return ExitFor(v.status());
  *(drag ? push.mutable_drag_target() : push.mutable_impulse()) = *v;
  push.set_drag_stiffness(o.drag_stiffness);
  push.set_drag_frames(o.drag_frames);
  auto conn = Connect(o.global);
  if (!conn.ok()) return ExitFor(conn.status());
  auto resp = conn->client->Poke(req);
  if (!resp.ok()) return ExitFor(resp.status());
  std::cout << resp->job().id() << " poke " << resp->poke_id() << ": body " << o.body
            << " acts from frame " << resp->earliest_frame() + 1 << " or later\n";
  return 0;
}

struct Command {
  CLI::App* app;
  int (*run)(const Options&);
};

void AddGlobalFlags(CLI::App& app, GlobalOptions& g) {
  app.add_option("--server", g.server,
                 "nimbusd address host:port; without it an embedded server runs in-process");
  app.add_option("--data-dir", g.data_dir,
                 "embedded server's data folder (default $NIMBUS_DATA_DIR or ~/.cache/nimbus)");
  app.add_option("--threads", g.threads, "embedded server: engine threads per job (0: all cores)");
  app.add_flag("-v,--verbose", g.verbose, "show server logs");
  app.add_option("--tls-ca", g.connect.tls_ca_file,
                 "PEM CA of the server's certificate: connect to --server over TLS");
  app.add_option("--tls-cert", g.connect.tls_cert_file,
                 "PEM client certificate, for servers that require mutual TLS");
  app.add_option("--tls-key", g.connect.tls_key_file, "PEM private key of --tls-cert");
  // The environment keeps the token out of shell history and `ps`.
  app.add_option("--token", g.connect.token, "access token (default $NIMBUS_TOKEN)")
      ->envname("NIMBUS_TOKEN");
}

void AddWatchFlags(CLI::App* c, WatchArgs& w) {
  c->add_option("--previews", w.previews,
                 "save preview grids (and pictures, for jobs with an image) in this folder");
  c->add_option("--preview-resolution", w.preview_resolution, "largest preview axis, voxels")
      ->capture_default_str();
  c->add_option("--preview-interval", w.preview_interval, "seconds between previews")
      ->capture_default_str();
  c->add_flag("--events", w.events, "print the job's events (as `nimbus events`) as they happen");
}

// A subcommand taking one job id.
CLI::App* AddJobCommand(CLI::App& app, Options& o, const std::string& name,
                        const std::string& help) {
  CLI::App* c = app.add_subcommand(name, help);
  c->add_option("job", o.job_id)->required();
  return c;
}

// render, submit and explore: the commands that send a spec.
std::vector<Command> AddSpecCommands(CLI::App& app, Options& o) {
  auto* render = app.add_subcommand("render", "submit a spec, show progress, fetch the .vdb");
  render->add_option("spec", o.spec_path, "spec file (.json or text format)")->required();
  render->add_option("-o,--output", o.out_path,
                     "main result path: .vdb, or .png/.exr for a picture-only job (a picture "
                     "beside a volume goes next to it)")
      ->required();
  render->add_option("--frames", o.frames_dir,
                     "folder for further result files (book pages, OUT.0001.vdb ...); "
                     "default: next to -o");
  AddWatchFlags(render, o.watch);
  auto* submit = app.add_subcommand("submit", "queue a spec and print the job id");
  submit->add_option("spec", o.spec_path, "spec file")->required();
  for (CLI::App* c : {render, submit}) {
    c->add_flag("--no-cache", o.no_cache,
                "run the job even if a finished job had the same spec (JobSpec.no_cache)");
    c->add_option("--shards", o.shards,
                  "split a chaos-game job into this many shards (JobSpec.shards)");
    c->add_option("--priority", o.priority, "0 to 100, higher runs first (default 50)");
  }
  auto* explore = app.add_subcommand(
      "explore", "draw random IFS, save a contact sheet and one spec per candidate");
  explore->add_option("spec", o.spec_path, "explore spec file (optional; flags override it)");
  explore->add_option("-o,--output", o.out_path, "folder for NAME.png and NAME.0001.json ...")
      ->capture_default_str();
  explore->add_option("--name", o.explore.name, "job and file name")->capture_default_str();
  // 0 would mean "the default" in the spec: refuse it here instead.
  explore->add_option("--count", o.explore.count, "candidates to keep (default 16)")
      ->check(CLI::Range(1, 1024));
  explore->add_option("--seed", o.explore.seed, "random seed (default 0)");
  explore->add_option("--size", o.explore.size, "thumbnail side in pixels (default 256)")
      ->check(CLI::Range(16, 1024));
  explore->add_option("--threshold", o.explore.threshold,
                      "keep IFS whose contraction is below this (default 0.9; det: 1.5)")
      ->check(CLI::Range(1e-6, 16.0));
  explore->add_option("--maps", o.explore.maps, "maps per IFS, a or a-b (default 3-5)");
  explore->add_option("--dim", o.explore.dim, "2 or 3 (default 2)")->check(CLI::Range(2, 3));
  explore->add_option("--measure", o.explore.measure,
                      "sv (largest singular value, default) or det (sum of |det|)");
  explore->add_option("--variations", o.explore.variations,
                      "variation names a map may get (e.g. spherical swirl)");
  explore->add_flag("--no-cache", o.no_cache, "run even if a finished job had the same spec");
  AddWatchFlags(explore, o.watch);
  o.explore.command = explore;
  return {{render, RunRender}, {submit, RunSubmit}, {explore, RunExplore}};
}

// Following, fetching and stopping jobs, and the server's health.
std::vector<Command> AddJobCommands(CLI::App& app, Options& o) {
  auto* watch = AddJobCommand(app, o, "watch", "follow a job until it ends");
  AddWatchFlags(watch, o.watch);
  auto* fetch = AddJobCommand(app, o, "fetch", "download a finished job's .vdb");
  fetch->add_option("-o,--output", o.out_path, "output path, with the file's extension")
      ->required();
  fetch->add_option("--file", o.fetch_file, "one of the job's further files (e.g. NAME.0003.vdb)");
  auto* get = AddJobCommand(app, o, "get", "print a job as JSON");
  auto* jobs = app.add_subcommand("jobs", "list jobs, newest first");
  jobs->add_option("--state", o.state_filter, "queued, running, succeeded, failed or cancelled");
  jobs->add_option("--limit", o.limit, "how many")->capture_default_str();
  auto* health = app.add_subcommand("health", "print the server's gRPC health; exit 0 if SERVING");
  health->add_option("--service", o.health_service,
                     "a service (nimbus.v1.NimbusService follows the job store); default: the server");
  auto* cancel = AddJobCommand(app, o, "cancel", "cancel a queued or running job");
  auto* poke = AddJobCommand(app, o, "poke", "push or drag a body of a running jelly job");
  poke->add_option("--body", o.body, "index into the spec's jelly.bodies")->required();
  poke->add_option("--impulse", o.impulse, "impulse x,y,z (mass x velocity change)");
  poke->add_option("--drag", o.drag, "drag the body towards the point x,y,z");
  poke->add_option("--stiffness", o.drag_stiffness, "drag spring stiffness (default 50)");
  poke->add_option("--drag-frames", o.drag_frames, "frames the drag lasts (default 1)");
  return {{watch, RunWatch},   {fetch, RunFetch},   {get, RunGet},  {jobs, RunJobs},
          {health, RunHealth}, {cancel, RunCancel}, {poke, RunPoke}};
}

// The queue: retention, priority, retry, the workers and a job's log.
std::vector<Command> AddQueueCommands(CLI::App& app, Options& o) {
  auto* pin =
      AddJobCommand(app, o, "pin", "keep a job's result (and assets) past the retention age");
  auto* unpin = AddJobCommand(app, o, "unpin", "let a pinned job's result expire again");
  auto* priority = AddJobCommand(app, o, "priority", "change a queued job's priority (0 to 100)");
  priority->add_option("priority", o.priority, "0 to 100, higher runs first")->required();
  auto* retry = AddJobCommand(app, o, "retry", "queue a failed or cancelled job again");
  auto* workers = app.add_subcommand("workers", "list the replicas sharing the job store");
  auto* events = AddJobCommand(app, o, "events", "print a job's event log, oldest first");
  auto* del = AddJobCommand(app, o, "delete", "delete a finished job and its result files");
  return {{pin, [](const Options& o) { return RunPin(o, true); }},
          {unpin, [](const Options& o) { return RunPin(o, false); }},
          {priority, RunPriority},
          {retry, RunRetry},
          {workers, RunWorkers},
          {events, RunEvents},
          {del, RunDelete}};
}

// validate and import-flame: local work, no server.
std::vector<Command> AddLocalCommands(CLI::App& app, Options& o) {
  auto* validate = app.add_subcommand("validate", "check a spec locally and summarise it");
  validate->add_option("spec", o.spec_path, "spec file")->required();
  auto* import = app.add_subcommand("import-flame", "convert a flam3 genome (.flam3) to a spec");
  import->add_option("flame", o.spec_path, "flam3 XML file")->required();
  import->add_option("-o,--output", o.out_path, "spec .json to write (default: stdout)");
  import->add_option("--genome", o.flame.genome, "a genome's name or index, when several");
  import->add_option("--iterations", o.flame.iterations,
                     "samples (default flam3's quality x width x height)");
  import->add_option("--seed", o.flame.seed, "random seed")->capture_default_str();
  import->add_flag("--picture", o.flame.picture,
                   "render a PNG the size of flam3's instead of a one-voxel-thick volume");
  return {{validate, RunValidate}, {import, RunImportFlame}};
}

// Declares the subcommands and their flags, bound to `o`; in help order.
std::vector<Command> AddCommands(CLI::App& app, Options& o) {
  std::vector<Command> all;
  for (auto add : {AddSpecCommands, AddJobCommands, AddQueueCommands, AddLocalCommands})
    for (Command& c : add(app, o)) all.push_back(std::move(c));
  return all;
}

}  // namespace

int main(int argc, char** argv) {
  nimbus::KeepFreedHeapForReuse();  // downloads stream 1 MiB chunks
  CLI::App app{"nimbus: grow fractal volumes (OpenVDB) with a Nimbus server"};
  app.require_subcommand(1);
  Options o;
  AddGlobalFlags(app, o.global);
  const std::vector<Command> commands = AddCommands(app, o);
  CLI11_PARSE(app, argc, argv);
  spdlog::set_level(o.global.verbose ? spdlog::level::info : spdlog::level::warn);
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ nimbusd %v");
  for (const Command& c : commands)
    if (c.app->parsed()) return c.run(o);
  return 0;
}
