#include "server/metrics.h"

#include <grpcpp/grpcpp.h>
#include <grpcpp/support/server_interceptor.h>
#include <prometheus/counter.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>

#include <array>
#include <atomic>
#include <chrono>
#include <map>
#include <mutex>
#include <set>
#include <unordered_map>

#include "absl/status/status.h"
#include "nimbus/v1/spec.pb.h"
#include "server/job_store.h"

namespace nimbus::server {

namespace {

using Clock = std::chrono::steady_clock;

const char* StateLabel(JobState s) {
  switch (s) {
    case JobState::kQueued:
      return "queued";
    case JobState::kRunning:
      return "running";
    case JobState::kSucceeded:
      return "succeeded";
    case JobState::kFailed:
      return "failed";
    case JobState::kCancelled:
      return "cancelled";
  }
  return "unknown";
}

constexpr JobState kStates[] = {JobState::kQueued, JobState::kRunning, JobState::kSucceeded,
                                JobState::kFailed, JobState::kCancelled};

// The generator's field name in JobSpec ("chaos_game", "set_ifs", ...).
std::string KindOf(const std::string& spec_bytes) {
  v1::JobSpec spec;
  if (!spec.ParseFromString(spec_bytes) || spec.generator_case() == 0) return "unknown";
  const auto* field = v1::JobSpec::descriptor()->FindFieldByNumber(spec.generator_case());
  return field ? field->name() : "unknown";
}

// "/nimbus.v1.NimbusService/SubmitJob" -> "nimbus.v1.NimbusService/SubmitJob".
std::string MethodLabel(const std::string& method) {
  return !method.empty() && method[0] == '/' ? method.substr(1) : method;
}

prometheus::Histogram::BucketBoundaries DurationBuckets() {
  return {1, 5, 15, 30, 60, 120, 300, 600, 1800, 3600, 4 * 3600, 12 * 3600};
}

prometheus::Histogram::BucketBoundaries LatencyBuckets() {
  return {0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10};
}

// Store calls: an embedded SQLite read takes tens of microseconds.
prometheus::Histogram::BucketBoundaries StoreBuckets() {
  return {0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5};
}

// PriorityBand's names, lowest first.
constexpr const char* kBands[] = {"low", "normal", "high"};
constexpr char kQueueDepthHelp[] =
    "Jobs waiting for a worker, by priority band (low 0-33, normal 34-66, high 67-100)";

}  // namespace

const char* PriorityBand(int priority) {
  return priority <= 33 ? kBands[0] : priority <= 66 ? kBands[1] : kBands[2];
}

struct ServiceMetrics::Impl {
  JobQueue* store;
  prometheus::Registry registry;
  prometheus::Family<prometheus::Gauge>& jobs =
      prometheus::BuildGauge()
          .Name("nimbus_jobs")
          .Help("Jobs in the store by state and kind (shards not counted)")
          .Register(registry);
  prometheus::Family<prometheus::Gauge>& queue_depth =
      prometheus::BuildGauge().Name("nimbus_queue_depth").Help(kQueueDepthHelp).Register(registry);
  prometheus::Family<prometheus::Histogram>& duration =
      prometheus::BuildHistogram()
          .Name("nimbus_job_duration_seconds")
          .Help("Run time of jobs seen to end, from their last start to their end, by kind")
          .Register(registry);
  prometheus::Family<prometheus::Counter>& work =
      prometheus::BuildCounter()
          .Name("nimbus_job_work_units_total")
          .Help(
              "Work units (points, set iterations, pages, frames, steps) of succeeded jobs, by "
              "kind")
          .Register(registry);
  prometheus::Family<prometheus::Counter>& preview_bytes =
      prometheus::BuildCounter()
          .Name("nimbus_http_preview_bytes_total")
          .Help("Preview bytes (PNG and density) sent by the HTTP port")
          .Register(registry);
  prometheus::Family<prometheus::Counter>& download_bytes =
      prometheus::BuildCounter()
          .Name("nimbus_http_download_bytes_total")
          .Help("Result bytes sent by the HTTP port")
          .Register(registry);
  prometheus::Family<prometheus::Counter>& refusals =
      prometheus::BuildCounter()
          .Name("nimbus_admission_refusals_total")
          .Help("SubmitJob calls refused, by status code")
          .Register(registry);
  prometheus::Family<prometheus::Histogram>& store_latency =
      prometheus::BuildHistogram()
          .Name("nimbus_store_call_duration_seconds")
          .Help("Job store calls (service, workers, sweeper, metrics), by call")
          .Register(registry);
  prometheus::Family<prometheus::Counter>& grpc_calls =
      prometheus::BuildCounter()
          .Name("nimbus_grpc_calls_total")
          .Help("gRPC calls by method and status code (HTTP API calls included)")
          .Register(registry);
  prometheus::Family<prometheus::Histogram>& grpc_latency =
      prometheus::BuildHistogram()
          .Name("nimbus_grpc_call_duration_seconds")
          .Help("gRPC call duration by method")
          .Register(registry);
  prometheus::Family<prometheus::Gauge>& workers = prometheus::BuildGauge()
                                                       .Name("nimbus_workers_alive")
                                                       .Help("Job workers of this replica")
                                                       .Register(registry);

  std::mutex scrape_mu;                                  // one scrape at a time: the caches below
  std::unordered_map<std::string, std::string> kind_of;  // job id -> kind
  std::set<std::string> ended;                           // job ids observed ended
  std::set<std::pair<std::string, std::string>> job_labels;
  // Each call's series, made at its first call.
  std::array<std::atomic<prometheus::Histogram*>, size_t(StoreCall::kCount)> store_calls{};

  explicit Impl(JobQueue* s) : store(s) {}
  void RefreshJobs();
};

void ServiceMetrics::Impl::RefreshJobs() {
  std::map<std::pair<std::string, std::string>, double> counts;
  std::unordered_map<std::string, std::string> seen_kinds;
  std::set<std::string> seen_ended;
  std::map<std::string, double> queued;  // by band
  ListOptions options;
  options.page_size = 500;
  for (int page = 0; page < 1000; ++page) {
    auto listed = store->List(options);
    if (!listed.ok()) break;
    for (const JobRecord& r : listed->jobs) {
      auto cached = kind_of.find(r.id);
      const std::string kind = cached != kind_of.end() ? cached->second : KindOf(r.spec);
      seen_kinds[r.id] = kind;
      counts[{StateLabel(r.state), kind}] += 1;
      if (r.state == JobState::kQueued) queued[PriorityBand(r.priority)] += 1;
      if (!IsTerminal(r.state)) continue;
      seen_ended.insert(r.id);
      if (ended.count(r.id)) continue;
      if (r.start_time > 0 && r.end_time >= r.start_time)
        duration.Add({{"kind", kind}}, DurationBuckets())
            .Observe((r.end_time - r.start_time) / 1e3);
      if (r.state == JobState::kSucceeded)
        work.Add({{"kind", kind}}).Increment(double(r.progress_done));
    }
    if (listed->next_page_token.empty()) break;
    options.page_token = listed->next_page_token;
  }
  kind_of = std::move(seen_kinds);
  ended = std::move(seen_ended);
  // Every state of every kind seen, zeros included, so a series never vanishes.
  for (const auto& [id, kind] : kind_of)
    for (JobState s : kStates) job_labels.insert({StateLabel(s), kind});
  for (const auto& labels : job_labels)
    jobs.Add({{"state", labels.first}, {"kind", labels.second}}).Set(counts[labels]);
  for (const char* band : kBands) queue_depth.Add({{"priority_band", band}}).Set(queued[band]);
}

ServiceMetrics::ServiceMetrics(JobQueue* store, int local_workers)
    : impl_(std::make_unique<Impl>(store)) {
  impl_->workers.Add({}).Set(local_workers);
  impl_->preview_bytes.Add({});
  impl_->download_bytes.Add({});
}

ServiceMetrics::~ServiceMetrics() = default;

void ServiceMetrics::CountGrpcCall(const std::string& method, int code, double seconds) {
  const std::string label = MethodLabel(method);
  const std::string code_name = absl::StatusCodeToString(absl::StatusCode(code));
  impl_->grpc_calls.Add({{"method", label}, {"code", code_name}}).Increment();
  impl_->grpc_latency.Add({{"method", label}}, LatencyBuckets()).Observe(seconds);
  if (code != 0 && label == "nimbus.v1.NimbusService/SubmitJob")
    impl_->refusals.Add({{"reason", code_name}}).Increment();
}

void ServiceMetrics::AddPreviewBytes(uint64_t bytes) {
  impl_->preview_bytes.Add({}).Increment(double(bytes));
}

void ServiceMetrics::AddDownloadBytes(uint64_t bytes) {
  impl_->download_bytes.Add({}).Increment(double(bytes));
}

void ServiceMetrics::ObserveStoreCall(StoreCall call, double seconds) {
  auto& slot = impl_->store_calls[size_t(call)];
  prometheus::Histogram* series = slot.load(std::memory_order_acquire);
  if (!series) {
    // Family::Add gives every caller with these labels the same series.
    series = &impl_->store_latency.Add({{"call", StoreCallName(call)}}, StoreBuckets());
    slot.store(series, std::memory_order_release);
  }
  series->Observe(seconds);
}

std::string ServiceMetrics::Scrape() {
  std::lock_guard<std::mutex> lock(impl_->scrape_mu);
  impl_->RefreshJobs();
  return prometheus::TextSerializer().Serialize(impl_->registry.Collect());
}

namespace {

// Times one server call from its creation to the status it sends.
class CallInterceptor : public grpc::experimental::Interceptor {
 public:
  CallInterceptor(ServiceMetrics* metrics, std::string method)
      : metrics_(metrics), method_(std::move(method)), start_(Clock::now()) {}
  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(
            grpc::experimental::InterceptionHookPoints::PRE_SEND_STATUS)) {
      const double seconds = std::chrono::duration<double>(Clock::now() - start_).count();
      metrics_->CountGrpcCall(method_, methods->GetSendStatus().error_code(), seconds);
    }
    methods->Proceed();
  }

 private:
  ServiceMetrics* metrics_;
  std::string method_;
  Clock::time_point start_;
};

class CallInterceptorFactory : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  explicit CallInterceptorFactory(ServiceMetrics* metrics) : metrics_(metrics) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(
      grpc::experimental::ServerRpcInfo* info) override {
    return new CallInterceptor(metrics_, info->method() ? info->method() : "");
  }

 private:
  ServiceMetrics* metrics_;
};

}  // namespace

std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>
ServiceMetrics::InterceptorFactory() {
  return std::make_unique<CallInterceptorFactory>(this);
}

}  // namespace nimbus::server
