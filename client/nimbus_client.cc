#include "client/nimbus_client.h"

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <condition_variable>
#include <deque>
#include <future>
#include <mutex>
#include <map>
#include <thread>

#include "absl/strings/str_cat.h"
#include "core/base/sha256.h"
#include "core/base/status_macros.h"
#include "nimbus/v1/nimbus_service.grpc.pb.h"
#include "proto/asset_paths.h"

namespace nimbus::client {

namespace {

absl::Status FromGrpc(const grpc::Status& s) {
  if (s.ok()) return absl::OkStatus();
  return absl::Status(static_cast<absl::StatusCode>(s.error_code()), s.error_message());
}

bool IsTerminal(v1::JobState s) {
  return s == v1::JOB_STATE_SUCCEEDED || s == v1::JOB_STATE_FAILED || s == v1::JOB_STATE_CANCELLED;
}

// Transport failures worth retrying: the server is restarting.
bool Retryable(const grpc::Status& s) {
  return s.error_code() == grpc::StatusCode::UNAVAILABLE ||
         s.error_code() == grpc::StatusCode::CANCELLED ||
         s.error_code() == grpc::StatusCode::UNKNOWN;
}

}  // namespace

struct NimbusClient::Impl {
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::NimbusService::Stub> stub;
  std::string token;
  // Metadata rather than call credentials: those gRPC sends only over TLS,
  // and a token to a loopback server without TLS is legitimate.
  void Authorize(grpc::ClientContext& ctx) const {
    if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
  }
};

NimbusClient::NimbusClient(std::shared_ptr<grpc::Channel> channel)
    : impl_(std::make_unique<Impl>()) {
  impl_->channel = std::move(channel);
  impl_->stub = v1::NimbusService::NewStub(impl_->channel);
}

NimbusClient::~NimbusClient() = default;

namespace {

grpc::ChannelArguments ChannelArgs() {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  // A deep receive window lets a download run ahead of the reader instead
  // of waiting a round trip for each window update.
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 16 << 20);
  // Reconnect quickly after a server restart.
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 100);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 1000);
  return args;
}

absl::StatusOr<std::string> ReadPem(const char* flag, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (!in.is_open() || text.empty())
    return absl::InvalidArgumentError(absl::StrCat(flag, " ", path, ": cannot read the file"));
  return text;
}

absl::StatusOr<std::shared_ptr<grpc::ChannelCredentials>> MakeChannelCredentials(
    const ConnectOptions& o) {
  if (o.tls_cert_file.empty() != o.tls_key_file.empty())
    return absl::InvalidArgumentError("--tls-cert and --tls-key go together");
  if (o.tls_ca_file.empty()) {
    if (!o.tls_cert_file.empty())
      return absl::InvalidArgumentError("--tls-cert needs --tls-ca (the server's CA)");
    return grpc::InsecureChannelCredentials();
  }
  grpc::SslCredentialsOptions ssl;
  NIMBUS_ASSIGN_OR_RETURN(ssl.pem_root_certs, ReadPem("--tls-ca", o.tls_ca_file));
  if (!o.tls_cert_file.empty()) {
    NIMBUS_ASSIGN_OR_RETURN(ssl.pem_cert_chain, ReadPem("--tls-cert", o.tls_cert_file));
    NIMBUS_ASSIGN_OR_RETURN(ssl.pem_private_key, ReadPem("--tls-key", o.tls_key_file));
  }
  return grpc::SslCredentials(ssl);
}

}  // namespace

std::unique_ptr<NimbusClient> NimbusClient::Connect(const std::string& target) {
  return std::make_unique<NimbusClient>(
      grpc::CreateCustomChannel(target, grpc::InsecureChannelCredentials(), ChannelArgs()));
}

absl::StatusOr<std::unique_ptr<NimbusClient>> NimbusClient::Connect(const std::string& target,
                                                                    const ConnectOptions& options) {
  NIMBUS_ASSIGN_OR_RETURN(auto credentials, MakeChannelCredentials(options));
  auto client =
      std::make_unique<NimbusClient>(grpc::CreateCustomChannel(target, credentials, ChannelArgs()));
  client->set_token(options.token);
  return client;
}

void NimbusClient::set_token(const std::string& token) { impl_->token = token; }

absl::Status NimbusClient::WaitForReady(double seconds) {
  const auto deadline =
      std::chrono::system_clock::now() + std::chrono::milliseconds(int64_t(seconds * 1000));
  if (!impl_->channel->WaitForConnected(deadline))
    return absl::UnavailableError("no Nimbus server answered in time");
  return absl::OkStatus();
}

// Debian ships no health.proto; the request and response are one field
// each: HealthCheckRequest.service (1, string), HealthCheckResponse.status
// (1, enum), encoded and decoded here.
absl::StatusOr<int> NimbusClient::Health(const std::string& service, double seconds) {
  if (service.size() > 127) return absl::InvalidArgumentError("service: longer than 127 bytes");
  std::string request;
  if (!service.empty()) request = std::string("\x0a") + char(service.size()) + service;
  grpc::Slice request_slice(request);
  grpc::ByteBuffer request_bytes(&request_slice, 1), response_bytes;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() +
                   std::chrono::milliseconds(int64_t(seconds * 1000)));
  std::promise<grpc::Status> finished;
  grpc::GenericStub(impl_->channel)
      .UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request_bytes,
                 &response_bytes, [&finished](grpc::Status s) { finished.set_value(s); });
  if (auto s = finished.get_future().get(); !s.ok()) return FromGrpc(s);
  std::vector<grpc::Slice> slices;
  if (!response_bytes.Dump(&slices).ok()) return absl::DataLossError("unreadable health answer");
  std::string bytes;
  for (const grpc::Slice& piece : slices)
    bytes.append(reinterpret_cast<const char*>(piece.begin()), piece.size());
  if (bytes.empty()) return 0;  // UNKNOWN, the default value, is not sent
  if (bytes.size() == 2 && bytes[0] == 0x08 && bytes[1] >= 0) return int(bytes[1]);
  return absl::DataLossError("unexpected health answer");
}

absl::StatusOr<v1::Job> NimbusClient::Submit(const v1::JobSpec& spec, const std::string& request_id,
                                             std::optional<int> priority) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::SubmitJobRequest req;
  *req.mutable_spec() = spec;
  req.set_request_id(request_id);
  if (priority.has_value()) req.set_priority(*priority);
  v1::SubmitJobResponse resp;
  if (auto s = impl_->stub->SubmitJob(&ctx, req, &resp); !s.ok()) return FromGrpc(s);
  return resp.job();
}

absl::StatusOr<v1::Job> NimbusClient::Get(const std::string& job_id) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::GetJobRequest req;
  req.set_job_id(job_id);
  v1::GetJobResponse resp;
  if (auto s = impl_->stub->GetJob(&ctx, req, &resp); !s.ok()) return FromGrpc(s);
  return resp.job();
}

absl::StatusOr<v1::ListJobsResponse> NimbusClient::List(const v1::ListJobsRequest& request) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::ListJobsResponse resp;
  if (auto s = impl_->stub->ListJobs(&ctx, request, &resp); !s.ok()) return FromGrpc(s);
  return resp;
}

absl::StatusOr<v1::Job> NimbusClient::Cancel(const std::string& job_id) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::CancelJobRequest req;
  req.set_job_id(job_id);
  v1::CancelJobResponse resp;
  if (auto s = impl_->stub->CancelJob(&ctx, req, &resp); !s.ok()) return FromGrpc(s);
  return resp.job();
}

absl::StatusOr<v1::Job> NimbusClient::Pin(const std::string& job_id, bool pinned) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::PinJobRequest req;
  req.set_job_id(job_id);
  req.set_pinned(pinned);
  v1::PinJobResponse resp;
  if (auto s = impl_->stub->PinJob(&ctx, req, &resp); !s.ok()) return FromGrpc(s);
  return resp.job();
}

absl::StatusOr<v1::Job> NimbusClient::SetPriority(const std::string& job_id, int priority) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::SetJobPriorityRequest req;
  req.set_job_id(job_id);
  req.set_priority(priority);
  v1::SetJobPriorityResponse resp;
  if (auto s = impl_->stub->SetJobPriority(&ctx, req, &resp); !s.ok()) return FromGrpc(s);
  return resp.job();
}

absl::StatusOr<v1::Job> NimbusClient::Retry(const std::string& job_id) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::RetryJobRequest req;
  req.set_job_id(job_id);
  v1::RetryJobResponse resp;
  if (auto s = impl_->stub->RetryJob(&ctx, req, &resp); !s.ok()) return FromGrpc(s);
  return resp.job();
}

absl::StatusOr<v1::ListWorkersResponse> NimbusClient::ListWorkers() {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::ListWorkersResponse resp;
  if (auto s = impl_->stub->ListWorkers(&ctx, v1::ListWorkersRequest(), &resp); !s.ok())
    return FromGrpc(s);
  return resp;
}

absl::StatusOr<v1::GetJobEventsResponse> NimbusClient::GetJobEvents(const std::string& job_id,
                                                                    int64_t after_seq,
                                                                    int32_t page_size) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::GetJobEventsRequest req;
  req.set_job_id(job_id);
  req.set_after_seq(after_seq);
  req.set_page_size(page_size);
  v1::GetJobEventsResponse resp;
  if (auto s = impl_->stub->GetJobEvents(&ctx, req, &resp); !s.ok()) return FromGrpc(s);
  return resp;
}

absl::StatusOr<uint64_t> NimbusClient::Delete(const std::string& job_id) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::DeleteJobRequest req;
  req.set_job_id(job_id);
  v1::DeleteJobResponse resp;
  if (auto s = impl_->stub->DeleteJob(&ctx, req, &resp); !s.ok()) return FromGrpc(s);
  return resp.freed_bytes();
}

absl::StatusOr<v1::PokeJobResponse> NimbusClient::Poke(const v1::PokeJobRequest& request) {
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  v1::PokeJobResponse resp;
  if (auto s = impl_->stub->PokeJob(&ctx, request, &resp); !s.ok()) return FromGrpc(s);
  return resp;
}

absl::StatusOr<v1::Job> NimbusClient::Watch(
    const std::string& job_id, const WatchOptions& options,
    const std::function<void(const v1::WatchJobResponse&)>& on_update) {
  v1::WatchJobRequest req;
  req.set_job_id(job_id);
  req.set_preview_resolution(options.preview_resolution);
  req.set_preview_interval_seconds(options.preview_interval_seconds);
  req.set_include_events(options.events);
  v1::Job last;
  auto give_up_at = std::chrono::steady_clock::now() +
                    std::chrono::milliseconds(int64_t(options.reconnect_timeout_seconds * 1000));
  while (true) {
    grpc::ClientContext ctx;
    impl_->Authorize(ctx);
    ctx.set_wait_for_ready(true);  // ride out a restarting server
    auto reader = impl_->stub->WatchJob(&ctx, req);
    v1::WatchJobResponse resp;
    bool got_any = false;
    while (reader->Read(&resp)) {
      got_any = true;
      last = resp.job();
      for (const v1::JobEvent& e : resp.events())
        req.set_events_after_seq(std::max(req.events_after_seq(), e.seq()));
      on_update(resp);
    }
    const grpc::Status s = reader->Finish();
    if (IsTerminal(last.state())) return last;
    if (!s.ok() && !Retryable(s)) return FromGrpc(s);
    if (got_any)
      give_up_at = std::chrono::steady_clock::now() +
                   std::chrono::milliseconds(int64_t(options.reconnect_timeout_seconds * 1000));
    if (std::chrono::steady_clock::now() > give_up_at)
      return absl::UnavailableError(
          absl::StrCat("lost the server while watching job ", job_id, ": ", s.error_message()));
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
}

namespace {

// Hashes a download's chunks on a second thread while this one receives,
// parses and writes the next: SHA-256 (about 1.7 GB/s here) is the longest
// part of a download, so it gets a thread to itself, and a queue of a few
// chunks keeps it from waiting for this thread to wake between chunks.
// Hashed buffers come back (keeping their capacity) for the next chunks,
// and the thread lives as long as the download, so nothing is allocated
// per chunk once the queue is full.
class ChunkHasher {
 public:
  explicit ChunkHasher(Sha256& hash) : hash_(hash) {
    thread_ = std::thread([this] { Run(); });
  }
  ~ChunkHasher() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  // Takes `data`'s bytes; leaves it holding a hashed chunk's buffer (empty,
  // with its capacity), or an empty string while none has come back.
  void Hash(std::string& data) {
    std::unique_lock<std::mutex> lock(mu_);
    cv_.wait(lock, [this] { return queued_.size() < kDepth; });
    queued_.push_back(std::move(data));
    data.clear();
    if (!spare_.empty()) {
      data.swap(spare_.back());
      spare_.pop_back();
    }
    lock.unlock();
    cv_.notify_all();
  }
  // Returns once every chunk is hashed.
  void Wait() {
    std::unique_lock<std::mutex> lock(mu_);
    cv_.wait(lock, [this] { return queued_.empty() && !busy_; });
  }

 private:
  static constexpr size_t kDepth = 8;  // 8 MiB with the server's 1 MiB chunks

  void Run() {
    std::unique_lock<std::mutex> lock(mu_);
    while (true) {
      cv_.wait(lock, [this] { return !queued_.empty() || stop_; });
      if (queued_.empty()) return;
      std::string chunk = std::move(queued_.front());
      queued_.pop_front();
      busy_ = true;
      lock.unlock();
      cv_.notify_all();  // room in the queue
      hash_.Update(chunk);
      lock.lock();
      busy_ = false;
      spare_.push_back(std::move(chunk));
      cv_.notify_all();
    }
  }

  Sha256& hash_;
  std::deque<std::string> queued_;
  std::vector<std::string> spare_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool busy_ = false, stop_ = false;
  std::thread thread_;
};

}  // namespace

absl::Status NimbusClient::Fetch(const std::string& job_id, const std::filesystem::path& path,
                                 const std::string& file_name) {
  const std::filesystem::path part = path.string() + ".part";
  std::error_code ec;
  uint64_t offset = std::filesystem::exists(part, ec) ? std::filesystem::file_size(part, ec) : 0;
  // Hashed as it arrives, so the file is not read a second time.
  Sha256 hash;
  if (offset > 0) NIMBUS_RETURN_IF_ERROR(HashFileInto(part, hash));
  std::string expected_sha;
  uint64_t total = 0;
  for (int attempt = 0;; ++attempt) {
    std::ofstream out(part, std::ios::binary | std::ios::app);
    if (!out) return absl::PermissionDeniedError(absl::StrCat("cannot write ", part.string()));
    grpc::ClientContext ctx;
    impl_->Authorize(ctx);
    ctx.set_wait_for_ready(true);
    v1::FetchResultRequest req;
    req.set_job_id(job_id);
    req.set_offset(offset);
    req.set_file_name(file_name);
    auto reader = impl_->stub->FetchResult(&ctx, req);
    v1::FetchResultResponse chunk;
    ChunkHasher hasher(hash);
    while (reader->Read(&chunk)) {
      if (!chunk.sha256().empty()) expected_sha = chunk.sha256();
      if (chunk.total_size()) total = chunk.total_size();
      if (chunk.offset() != offset)
        return absl::DataLossError(
            absl::StrCat("server sent offset ", chunk.offset(), ", expected ", offset));
      offset += chunk.data().size();
      out.write(chunk.data().data(), std::streamsize(chunk.data().size()));
      hasher.Hash(*chunk.mutable_data());
    }
    hasher.Wait();
    out.close();
    if (!out) {
      ctx.TryCancel();
      reader->Finish();
      return absl::ResourceExhaustedError(
          absl::StrCat("cannot write ", part.string(), " (disk full?)"));
    }
    const grpc::Status s = reader->Finish();
    if (s.ok()) break;
    if (!Retryable(s) || attempt >= 20) {
      if (s.error_code() == grpc::StatusCode::OUT_OF_RANGE) std::filesystem::remove(part, ec);
      return FromGrpc(s);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(250));
  }
  if (offset != total)
    return absl::DataLossError(absl::StrCat("downloaded ", offset, " of ", total, " bytes"));
  const std::string sha = hash.HexDigest();
  if (sha != expected_sha) {
    std::filesystem::remove(part, ec);
    return absl::DataLossError(absl::StrCat("sha256 mismatch for ", path.string(), ": got ", sha,
                                            ", server says ", expected_sha));
  }
  std::filesystem::rename(part, path, ec);
  if (ec) return absl::InternalError(absl::StrCat("rename to ", path.string(), ": ", ec.message()));
  return absl::OkStatus();
}

absl::StatusOr<v1::UploadAssetResponse> NimbusClient::UploadBytes(const std::string& file_name,
                                                                  const std::string& data,
                                                                  const std::string& sha256,
                                                                  uint64_t size) {
  constexpr size_t kChunk = size_t{1} << 20;
  grpc::ClientContext ctx;
  impl_->Authorize(ctx);
  ctx.set_wait_for_ready(true);
  v1::UploadAssetResponse resp;
  auto writer = impl_->stub->UploadAsset(&ctx, &resp);
  v1::UploadAssetRequest req;
  req.set_sha256(sha256);
  req.set_size_bytes(size);
  req.set_file_name(file_name);
  size_t pos = 0;
  do {
    const size_t n = std::min(kChunk, data.size() - pos);
    req.set_data(data.substr(pos, n));
    pos += n;
    // A failed write means the server already ended the call; Finish says why.
    if (!writer->Write(req)) break;
    req.Clear();
  } while (pos < data.size());
  writer->WritesDone();
  if (auto s = writer->Finish(); !s.ok()) return FromGrpc(s);
  return resp;
}

absl::StatusOr<std::string> NimbusClient::UploadFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat(path.string(), ": cannot read the file"));
  std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string sha = Sha256Hex(data);
  auto resp = UploadBytes(path.filename().string(), data, sha, data.size());
  if (!resp.ok())
    return absl::Status(resp.status().code(),
                        absl::StrCat("upload of ", path.string(), ": ", resp.status().message()));
  return resp->sha256();
}

absl::Status NimbusClient::UploadSpecAssets(v1::JobSpec& spec,
                                            const std::filesystem::path& base_dir) {
  spec::ResolveAssetPaths(spec, base_dir);
  absl::Status status;
  // The same file named twice is uploaded once.
  std::map<std::string, std::string> uploaded;
  spec::ForEachAsset(spec, [&](const std::string& field, v1::Asset& asset) {
    if (!status.ok() || asset.source_case() != v1::Asset::kPath) return;
    auto it = uploaded.find(asset.path());
    if (it == uploaded.end()) {
      auto sha = UploadFile(asset.path());
      if (!sha.ok()) {
        status = absl::Status(sha.status().code(),
                              absl::StrCat(field, ".path: ", sha.status().message()));
        return;
      }
      it = uploaded.emplace(asset.path(), *sha).first;
    }
    asset.set_label(std::filesystem::path(asset.path()).filename().string());
    asset.set_sha256(it->second);  // replaces the path (one of)
  });
  return status;
}

}  // namespace nimbus::client
