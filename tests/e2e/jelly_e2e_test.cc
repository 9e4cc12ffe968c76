// Jelly jobs against a real nimbusd on loopback: frames stream while the
// job runs, a poke on a running job changes the frames from the one it
// acts at and leaves every earlier frame byte-identical to an unpoked run,
// and pokes the service cannot apply are refused with the right code.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>

#include "client/nimbus_client.h"
#include "core/base/sha256.h"
#include "core/io/metadata_keys.h"
#include "core/io/vdb_io.h"
#include "proto/spec_io.h"
#include "tests/support/nimbusd_process.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using client::NimbusClient;
using ::testing::HasSubstr;

constexpr uint32_t kFrames = 60;

// The Sierpinski example with many leaves on a small grid: tens of
// milliseconds a frame, so a poke lands mid-run.
v1::JobSpec SlowSierpinski() {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/jelly_sierpinski.json"));
  EXPECT_TRUE(spec.ok()) << spec.status();
  spec->mutable_grid()->set_resolution(0, 32);
  spec->mutable_jelly()->set_frames(kFrames);
  spec->mutable_jelly()->set_depth(9);
  return *spec;
}

class JellyE2E : public ::testing::Test {
 protected:
  void SetUp() override {
    server_.set_args({"--workers", "1", "--threads-per-job", "2", "--log-level", "warn",
                      "--min-free-disk-mib", "0"});
    ASSERT_TRUE(server_.Start().ok());
    client_ = NimbusClient::Connect(server_.target());
    poker_ = NimbusClient::Connect(server_.target());
    ASSERT_TRUE(client_->WaitForReady(20).ok()) << "nimbusd did not answer";
  }

  // Fetches every frame of a finished job; returns their sha256.
  std::vector<std::string> FrameHashes(const std::string& id, const std::string& tag) {
    std::vector<std::string> out;
    for (uint32_t f = 1; f <= kFrames; ++f) {
      char name[64];
      std::snprintf(name, sizeof name, "jelly_sierpinski.%04u.vdb", f);
      const auto path = dir_ / (tag + name);
      EXPECT_TRUE(client_->Fetch(id, path, name).ok()) << name;
      out.push_back(Sha256File(path).value_or(""));
    }
    return out;
  }

  int64_t PokesIn(const std::string& tag, uint32_t frame) {
    char name[64];
    std::snprintf(name, sizeof name, "jelly_sierpinski.%04u.vdb", frame);
    auto v = ReadVdbFile(dir_ / (tag + name));
    EXPECT_TRUE(v.ok()) << v.status();
    const MetaValue* m = v.ok() ? v->Find(meta_key::kJellyPokes) : nullptr;
    return m ? std::get<int64_t>(*m) : -1;
  }

  testing::TempDir dir_;
  testing::NimbusdProcess server_{dir_ / "data"};
  std::unique_ptr<NimbusClient> client_, poker_;
};

v1::PokeJobRequest Impulse(const std::string& id, int body, double x) {
  v1::PokeJobRequest req;
  req.set_job_id(id);
  req.mutable_push()->set_body(body);
  req.mutable_push()->mutable_impulse()->set_x(x);
  return req;
}

TEST_F(JellyE2E, APokeChangesTheFramesFromItsFrameOnAndNoEarlierOne) {
  const v1::JobSpec spec = SlowSierpinski();
  auto poked = client_->Submit(spec);
  ASSERT_TRUE(poked.ok()) << poked.status();
  std::atomic<bool> sent{false};
  absl::StatusOr<v1::PokeJobResponse> answer;
  absl::Status bad_body, no_action;
  auto done = client_->Watch(poked->id(), {}, [&](const v1::WatchJobResponse& r) {
    if (sent || r.job().state() != v1::JOB_STATE_RUNNING || r.job().progress().unit() != "frames" ||
        r.job().progress().done() < 3)
      return;
    sent = true;
    bad_body = poker_->Poke(Impulse(poked->id(), 4, 1)).status();
    v1::PokeJobRequest empty;
    empty.set_job_id(poked->id());
    no_action = poker_->Poke(empty).status();
    answer = poker_->Poke(Impulse(poked->id(), 0, 4));
  });
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  ASSERT_TRUE(sent) << "the job finished before it could be poked";
  ASSERT_TRUE(answer.ok()) << answer.status();
  EXPECT_EQ(bad_body.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(bad_body.message()), HasSubstr("push.body: no body 4"));
  EXPECT_EQ(no_action.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(no_action.message()), HasSubstr("push: set impulse or drag_target"));
  EXPECT_EQ(done->stats().at("jelly_pokes"), 1u);
  const uint64_t earliest = answer->earliest_frame();
  ASSERT_GE(earliest, 3u);
  ASSERT_LT(earliest, kFrames);

  // The same spec, unpoked.
  auto plain = client_->Submit(spec);
  ASSERT_TRUE(plain.ok());
  auto plain_done = client_->Watch(plain->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(plain_done.ok() && plain_done->state() == v1::JOB_STATE_SUCCEEDED);

  const auto a = FrameHashes(poked->id(), "poked_");
  const auto b = FrameHashes(plain->id(), "plain_");
  size_t first = 0;
  while (first < kFrames && a[first] == b[first]) ++first;
  // Every frame before the poke's is the unpoked run's, byte for byte; the
  // poke's frame and every later one differ, and say they saw one poke.
  ASSERT_GE(first, earliest);
  ASSERT_LT(first, size_t(kFrames));
  for (size_t f = first; f < kFrames; ++f) EXPECT_NE(a[f], b[f]) << "frame index " << f;
  EXPECT_EQ(PokesIn("poked_", uint32_t(first)), 0);
  EXPECT_EQ(PokesIn("poked_", uint32_t(first + 1)), 1);
  EXPECT_EQ(PokesIn("poked_", kFrames), 1);
  EXPECT_EQ(PokesIn("plain_", kFrames), 0);

  // A finished job cannot be poked.
  auto late = poker_->Poke(Impulse(poked->id(), 0, 1));
  EXPECT_EQ(late.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(std::string(late.status().message()), HasSubstr("SUCCEEDED"));
}

TEST_F(JellyE2E, PokesTheServiceCannotApplyAreRefused) {
  auto missing = client_->Poke(Impulse("no-such-job", 0, 1));
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  ASSERT_TRUE(spec.ok());
  spec->mutable_grid()->set_resolution(0, 16);
  spec->mutable_chaos_game()->set_iterations(1000);
  auto chaos = client_->Submit(*spec);
  ASSERT_TRUE(chaos.ok());
  auto not_jelly = client_->Poke(Impulse(chaos->id(), 0, 1));
  EXPECT_EQ(not_jelly.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(std::string(not_jelly.status().message()), HasSubstr("not a jelly job"));
  auto no_id = client_->Poke(Impulse("", 0, 1));
  EXPECT_EQ(no_id.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(no_id.status().message()), HasSubstr("job_id"));
}

}  // namespace
}  // namespace nimbus
