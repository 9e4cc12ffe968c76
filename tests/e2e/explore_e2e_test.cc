// Explore jobs through a real nimbusd: the contact sheet and the candidates'
// specs are result files, byte-identical on one and two threads; every
// candidate is below the threshold by an independent oracle; a candidate's
// spec submitted as a normal job renders.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "absl/strings/str_format.h"
#include "core/grid/contact_sheet.h"
#include "core/io/image_io.h"
#include "tests/support/contraction_oracle.h"
#include "tests/support/server_fixture.h"

namespace nimbus {
namespace {

std::string ReadBytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

v1::JobSpec SmallExplore() {
  v1::JobSpec spec = testing::LoadExample("explore.json");
  v1::Explore& e = *spec.mutable_explore();
  e.set_count(4);
  e.set_thumbnail_size(48);
  e.set_thumbnail_iterations(uint64_t{1} << 16);
  spec.set_no_cache(true);
  return spec;
}

// The files of a finished explore job: the sheet first, then the specs.
struct Fetched {
  std::string sheet;
  std::vector<std::string> specs;
};

Fetched RunToFiles(client::NimbusClient& client, const v1::JobSpec& spec,
                   const std::filesystem::path& dir) {
  Fetched out;
  auto job = client.Submit(spec);
  EXPECT_TRUE(job.ok()) << job.status();
  if (!job.ok()) return out;
  auto done = client.Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  EXPECT_TRUE(done.ok()) << done.status();
  if (!done.ok()) return out;
  EXPECT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  auto full = client.Get(job->id());
  EXPECT_TRUE(full.ok());
  if (!full.ok()) return out;
  std::filesystem::create_directories(dir);
  EXPECT_TRUE(client.Fetch(job->id(), dir / "sheet.png").ok());
  out.sheet = ReadBytes(dir / "sheet.png");
  for (const v1::ResultFile& f : full->result().files()) {
    EXPECT_TRUE(client.Fetch(job->id(), dir / f.file_name(), f.file_name()).ok());
    out.specs.push_back(ReadBytes(dir / f.file_name()));
  }
  return out;
}

class ExploreE2E : public testing::NimbusdTest {};

TEST_F(ExploreE2E, SameBytesOnOneAndTwoThreadsAndCandidatesRender) {
  const v1::JobSpec spec = SmallExplore();
  const Fetched two = RunToFiles(*client_, spec, dir_ / "two");
  ASSERT_EQ(two.specs.size(), 4u);
  const Fetched again = RunToFiles(*client_, spec, dir_ / "again");
  EXPECT_TRUE(again.sheet == two.sheet);
  EXPECT_EQ(again.specs, two.specs);

  testing::NimbusdProcess single(dir_ / "data1",
                                 {"--workers", "1", "--threads-per-job", "1", "--log-level",
                                  "warn"});
  ASSERT_TRUE(single.Start().ok());
  auto one_client = client::NimbusClient::Connect(single.target());
  ASSERT_TRUE(one_client->WaitForReady(20).ok());
  const Fetched one = RunToFiles(*one_client, spec, dir_ / "one");
  EXPECT_TRUE(one.sheet == two.sheet) << "the sheet differs between 1 and 2 threads";
  EXPECT_EQ(one.specs, two.specs);

  // The sheet's size, read back with libpng, is the layout's.
  auto png = ReadPngPixels(dir_ / "two" / "sheet.png");
  ASSERT_TRUE(png.ok()) << png.status();
  const SheetLayout layout = ContactSheetLayout(4, 48, spec.explore().columns());
  EXPECT_EQ(png->width, layout.width());
  EXPECT_EQ(png->height, layout.height());
  EXPECT_EQ(png->channels, 3);

  // Every candidate is below the threshold, by the oracle.
  const double threshold = spec.explore().threshold() == 0 ? 0.9 : spec.explore().threshold();
  const int dims = spec.explore().dimensions() == 0 ? 2 : spec.explore().dimensions();
  std::vector<v1::JobSpec> candidates;
  for (int i = 1; i <= 4; ++i) {
    auto cand =
        spec::LoadSpecFile(dir_ / "two" / absl::StrFormat("%s.%04d.json", spec.name(), i));
    ASSERT_TRUE(cand.ok()) << cand.status();
    double worst = 0;
    for (const v1::Map& m : cand->chaos_game().ifs().maps()) {
      ASSERT_EQ(m.steps_size(), 1);
      const auto& v = m.steps(0).matrix().values();
      const std::vector<double> values(v.begin(), v.end());
      worst = std::max(worst,
                       testing::OracleLargestSingularValue(testing::LinearBlock(values, dims)));
    }
    EXPECT_LT(worst, threshold) << "candidate " << i;
    candidates.push_back(*cand);
  }

  // A candidate's spec is a normal job: render it small.
  v1::JobSpec big = candidates[0];
  big.mutable_chaos_game()->set_iterations(uint64_t{1} << 20);
  big.mutable_image()->set_width(64);
  big.set_no_cache(true);
  auto job = client_->Submit(big);
  ASSERT_TRUE(job.ok()) << job.status();
  auto done = client_->Watch(job->id(), {}, [](const v1::WatchJobResponse&) {});
  ASSERT_TRUE(done.ok()) << done.status();
  ASSERT_EQ(done->state(), v1::JOB_STATE_SUCCEEDED) << done->error();
  ASSERT_TRUE(client_->Fetch(job->id(), dir_ / "cand.png").ok());
  auto picture = ReadPngPixels(dir_ / "cand.png");
  ASSERT_TRUE(picture.ok()) << picture.status();
  EXPECT_EQ(picture->width, 64);
  uint64_t lit = 0;
  for (uint16_t s : picture->samples) lit += s > 0;
  EXPECT_GT(lit, 100u);
}

}  // namespace
}  // namespace nimbus
