// Client library for nimbus.v1.NimbusService. gRPC is hidden behind a pimpl;
// callers see protobuf messages and absl::Status only.
#pragma once

#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "nimbus/v1/nimbus_service.pb.h"
#include "nimbus/v1/spec.pb.h"

namespace grpc {
class Channel;
}

namespace nimbus::client {

struct WatchOptions {
  /// Largest preview axis in voxels; 0 for no previews.
  uint32_t preview_resolution = 0;
  double preview_interval_seconds = 1.0;
  /// How long to keep reconnecting when the server goes away mid-watch.
  double reconnect_timeout_seconds = 120.0;
  /// Also receive the job's event log as it grows (WatchJobResponse.events);
  /// a watch resumed after a reconnect repeats none.
  bool events = false;
};

/// How to reach a server that wants TLS or a token (docs/operator_guide.md
/// "Security"). All empty: plaintext, no token.
struct ConnectOptions {
  /// PEM CA bundle that signed the server's certificate: connect over TLS.
  std::string tls_ca_file;
  /// PEM client certificate and key, for servers that require mutual TLS.
  std::string tls_cert_file, tls_key_file;
  /// Sent as `authorization: Bearer TOKEN` with every call.
  std::string token;
};

/// @brief Blocking client. Thread-compatible; one call at a time per object.
class NimbusClient {
 public:
  explicit NimbusClient(std::shared_ptr<grpc::Channel> channel);
  /// Connects to host:port over plaintext.
  static std::unique_ptr<NimbusClient> Connect(const std::string& target);
  /// Connects with TLS and/or a token. INVALID_ARGUMENT names an unreadable
  /// PEM file or a client certificate without its key.
  static absl::StatusOr<std::unique_ptr<NimbusClient>> Connect(const std::string& target,
                                                               const ConnectOptions& options);
  /// The token sent with every later call (empty: none).
  void set_token(const std::string& token);
  ~NimbusClient();

  /// `priority` 0..100 (higher claimed first); the server's default, 50,
  /// when unset.
  absl::StatusOr<v1::Job> Submit(const v1::JobSpec& spec, const std::string& request_id = "",
                                 std::optional<int> priority = std::nullopt);
  absl::StatusOr<v1::Job> Get(const std::string& job_id);
  absl::StatusOr<v1::ListJobsResponse> List(const v1::ListJobsRequest& request);
  absl::StatusOr<v1::Job> Cancel(const std::string& job_id);
  /// Pins (or, with `pinned` false, unpins) a job's result against expiry.
  absl::StatusOr<v1::Job> Pin(const std::string& job_id, bool pinned);
  /// Changes a queued job's priority (0..100).
  absl::StatusOr<v1::Job> SetPriority(const std::string& job_id, int priority);
  /// Queues a FAILED or CANCELLED job again; returns the new job.
  absl::StatusOr<v1::Job> Retry(const std::string& job_id);
  /// The replicas sharing the server's job store.
  absl::StatusOr<v1::ListWorkersResponse> ListWorkers();
  /// One page of a job's event log, after `after_seq`.
  absl::StatusOr<v1::GetJobEventsResponse> GetJobEvents(const std::string& job_id,
                                                        int64_t after_seq, int32_t page_size);
  /// Deletes a finished job and its result files; returns the bytes freed.
  absl::StatusOr<uint64_t> Delete(const std::string& job_id);
  /// Pushes or drags a body of a running jelly job (docs/jelly.md).
  absl::StatusOr<v1::PokeJobResponse> Poke(const v1::PokeJobRequest& request);

  /// Streams updates to `on_update` until the job ends, reconnecting after
  /// transport failures (a server restart) and resuming the watch. Returns
  /// the job's final view.
  absl::StatusOr<v1::Job> Watch(const std::string& job_id, const WatchOptions& options,
                                const std::function<void(const v1::WatchJobResponse&)>& on_update);

  /// Downloads the result to `path`. An existing `path + ".part"` resumes
  /// from its size. The SHA-256 is verified before the file is renamed into
  /// place; a mismatch deletes the partial file and is DATA_LOSS.
  /// `file_name` picks one of Job.result.files (a book page) instead of
  /// the main file; a running job's listed files can already be fetched.
  absl::Status Fetch(const std::string& job_id, const std::filesystem::path& path,
                     const std::string& file_name = "");

  /// Uploads a local mesh or grid file (docs/assets.md); returns its sha256.
  absl::StatusOr<std::string> UploadFile(const std::filesystem::path& path);
  /// Uploads `data` announcing `sha256` and `size` (normally the data's own:
  /// tests announce others to see the server refuse). `file_name`'s
  /// extension tells the server the format.
  absl::StatusOr<v1::UploadAssetResponse> UploadBytes(const std::string& file_name,
                                                      const std::string& data,
                                                      const std::string& sha256, uint64_t size);
  /// Uploads every asset the spec names by local path and replaces the
  /// path by the sha256. Relative paths resolve against `base_dir`.
  absl::Status UploadSpecAssets(v1::JobSpec& spec, const std::filesystem::path& base_dir);

  /// Waits until the server answers, up to `seconds`.
  absl::Status WaitForReady(double seconds);

  /// grpc.health.v1.Health/Check of `service` ("" is the whole server),
  /// waiting at most `seconds`: the ServingStatus number (1 SERVING,
  /// 2 NOT_SERVING). NOT_FOUND for a service the server does not know.
  absl::StatusOr<int> Health(const std::string& service, double seconds);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace nimbus::client
