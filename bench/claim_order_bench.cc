// Claims per second under the claim order (docs/operator_guide.md "Claim
// order") with a deep queue: 10,000 QUEUED jobs from 10 owners at one
// priority, plus 100 at a higher one, in a SQLite store and in a
// PostgreSQL one (a private server, as the tests start; skipped when not
// installed). One claimer claims and completes jobs one at a time; the
// figure is claims (each with its completion) per second over the first
// 2,000 claims. Figures, not assertions.
//   build/bin/claim_order_bench [queued jobs, default 10000] [claims, default 2000]
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>

#include "absl/strings/str_cat.h"
#include "server/job_store.h"
#include "tests/support/job_store_factory.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using Clock = std::chrono::steady_clock;
constexpr int kOwners = 10;

void Run(testing::StoreKind kind, int queued, int claims) {
  testing::TempDir dir;
  auto where = testing::StoreLocation::Fresh(kind, dir.path());
  if (!where.ok()) {
    std::printf("%-8s skipped: %s\n", testing::StoreKindName(kind).c_str(),
                std::string(where.status().message()).c_str());
    return;
  }
  auto store = where->Open();
  if (!store.ok()) {
    std::printf("%-8s: %s\n", testing::StoreKindName(kind).c_str(),
                store.status().ToString().c_str());
    return;
  }
  const server::TimeMs t0 = 1'700'000'000'000;
  const auto fill_start = Clock::now();
  for (int i = 0; i < queued + 100; ++i) {
    server::NewJob job;
    job.id = absl::StrCat("j", i);
    job.spec = "spec";
    job.owner = absl::StrCat("owner-", i % kOwners);
    job.priority = i < queued ? 50 : 70;
    if (!(*store)->Create(job, t0 + i).ok()) std::exit(1);
  }
  const double fill_s = std::chrono::duration<double>(Clock::now() - fill_start).count();
  const auto start = Clock::now();
  int done = 0;
  for (; done < claims; ++done) {
    auto c = (*store)->ClaimNext("bench/w0", t0 + 1'000'000 + done, 60'000);
    if (!c.ok() || !c->has_value()) break;
    if (!(*store)->Complete((**c).id, "bench/w0", server::Completion{}, t0 + 2'000'000 + done).ok())
      std::exit(1);
  }
  const double s = std::chrono::duration<double>(Clock::now() - start).count();
  std::printf(
      "%-8s %6d queued from %d owners (filled in %.1f s): %5d claims+completions in "
      "%.2f s = %7.0f claims/s\n",
      testing::StoreKindName(kind).c_str(), queued + 100, kOwners, fill_s, done, s, done / s);
}

}  // namespace
}  // namespace nimbus

int main(int argc, char** argv) {
  const int queued = argc > 1 ? std::atoi(argv[1]) : 10'000;
  const int claims = argc > 2 ? std::atoi(argv[2]) : 2'000;
  nimbus::Run(nimbus::testing::StoreKind::kSqlite, queued, claims);
  nimbus::Run(nimbus::testing::StoreKind::kPostgres, queued, claims);
  return 0;
}
