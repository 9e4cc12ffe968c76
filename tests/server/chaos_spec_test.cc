// The chaos-game part of the spec (issue 3) from JSON to the runner's VDB:
// variations, final transforms, colour, memory limits, bad points and
// convergence.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstring>
#include <set>
#include <tuple>

#include "tests/support/attractors.h"
#include "core/chaos/variations.h"
#include "proto/spec_convert.h"
#include "server/memory_admission.h"
#include "proto/spec_io.h"
#include "server/job_runner.h"
#include "server/result_store.h"
#include "tests/support/fake_job_context.h"
#include "tests/support/test_util.h"

namespace nimbus {
namespace {

using ::testing::HasSubstr;

v1::JobSpec Parse(const std::string& json) {
  auto spec = spec::ParseSpec(json, spec::SpecFormat::kJson);
  EXPECT_TRUE(spec.ok()) << spec.status();
  return spec.ok() ? *spec : v1::JobSpec{};
}

// Two maps: a contraction and one map built around `map_json`.
std::string SpecWith(const std::string& map_json, const std::string& extra_ifs = "",
                     const std::string& extra_cg = "", int resolution = 32,
                     uint64_t iterations = 200000) {
  return absl::StrCat(R"({"name": "t", "grid": {"resolution": [)", resolution,
                      R"(], "bounds_min": {"x": -2, "y": -2, "z": -2},
            "bounds_max": {"x": 2, "y": 2, "z": 2}},
  "chaos_game": {"ifs": {"maps": [
      {"steps": [{"translate": {"x": 0.5}}, {"scale": {"uniform": 0.5}}]},
      )",
                      map_json, "]", extra_ifs, R"(}, "iterations": ")", iterations, "\"",
                      extra_cg, "}}");
}

absl::StatusOr<JobPlan> Convert(const std::string& json, spec::Limits limits = {}) {
  return spec::ConvertSpec(Parse(json), limits);
}

// Conversion, then the server's memory admission on 2 threads.
absl::StatusOr<server::MemoryAdmission> Admit(const std::string& json, spec::Limits limits = {}) {
  auto plan = Convert(json, limits);
  if (!plan.ok()) return plan.status();
  return server::AdmitMemory(*plan, limits, 2);
}


TEST(ChaosSpec, EveryVariationIsWiredThroughTheSpec) {
  for (VariationKind kind : AllVariations()) {
    const std::string name(VariationName(kind));
    const std::string map = absl::StrCat(
        R"({"steps": [{"translate": {"y": 0.2}}, {"scale": {"uniform": 0.6}}],
            "variations": [{"name": ")",
        name, R"(", "weight": 0.7, "params": [0.5, 1.5, 0.25, 2]}]})");
    auto job = Convert(SpecWith(map));
    ASSERT_TRUE(job.ok()) << name << ": " << job.status();
    const PointMap& m = job->point_run()->ifs.maps[1];
    ASSERT_EQ(m.variations.size(), 1u) << name;
    EXPECT_EQ(m.variations[0].kind, kind) << name;
    EXPECT_EQ(m.variations[0].weight, 0.7) << name;
    EXPECT_EQ(m.variations[0].params[1], 1.5) << name;
    // The converted map is pre-affine then the weighted variation.
    const Vec3 p{0.3, -0.2, 0.4};
    Rng r1(5, 0), r2(5, 0);
    const Vec3 got = m.Apply(p, r1);
    const Vec3 want = 0.7 * EvaluateVariation(m.variations[0], m.pre.Apply(p), m.pre, r2);
    EXPECT_EQ(got, want) << name;
    // And the job runs end to end without crashing.
    testing::FakeJobContext ctx;
    ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok()) << name;
    EXPECT_TRUE(ctx.stats.count("reseeded")) << name;
  }
}

TEST(ChaosSpec, UnknownVariationNamesItsPath) {
  auto job = Convert(SpecWith(R"({"variations": [{"name": "nope"}]})", R"(, "final": {})"));
  EXPECT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument);
  auto fin = Convert(SpecWith(R"({"steps": [{"scale": {"uniform": 0.4}}]})",
                              R"(, "final": {"variations": [{"name": "nope"}]})"));
  EXPECT_THAT(std::string(fin.status().message()),
              HasSubstr("chaos_game.ifs.final.variations[0].name"));
}

TEST(ChaosSpec, FinalAndArcsConvert) {
  auto job = Convert(SpecWith(R"({"steps": [{"scale": {"uniform": 0.4}}]})",
                              R"(, "final": {"variations": [{"name": "spherical"}]},
                                 "arcs": {"angle_per_unit": 0.5, "amplitude": 0.1,
                                          "frequency": 2})"));
  ASSERT_TRUE(job.ok()) << job.status();
  const Ifs& ifs = job->point_run()->ifs;
  ASSERT_TRUE(ifs.final_map.has_value());
  EXPECT_EQ(ifs.final_map->variations[0].kind, VariationKind::kSpherical);
  ASSERT_TRUE(ifs.arcs.has_value());
  EXPECT_EQ(ifs.arcs->angle_per_unit, 0.5);
  EXPECT_EQ(ifs.arcs->amplitude, 0.1);
  EXPECT_EQ(ifs.arcs->frequency, 2);
  // The final map does not take part in the walk's probabilities.
  EXPECT_EQ(ifs.probabilities.size(), 2u);
}

TEST(ChaosSpec, ColourOptionsConvertWithDefaults) {
  const std::string map = R"({"steps": [{"scale": {"uniform": 0.4}}], "color": 0.8})";
  auto plain = Convert(SpecWith(map));
  ASSERT_TRUE(plain.ok());
  EXPECT_EQ(plain->point_run()->color.mode, ColorMode::kNone);
  EXPECT_FALSE(plain->density.color);

  auto addr = Convert(SpecWith(map, "", R"(, "color": {})"));
  ASSERT_TRUE(addr.ok()) << addr.status();
  EXPECT_EQ(addr->point_run()->color.mode, ColorMode::kAddress);
  EXPECT_EQ(addr->point_run()->color.blend, 0.05);
  EXPECT_TRUE(addr->density.color);
  EXPECT_TRUE(addr->density.palette.is_sine());

  auto stops = Convert(SpecWith(map, "", R"(, "color": {"mode": "COLOR_MODE_MAP", "blend": 0.5,
      "address_grid": true, "palette": {"stops": [
        {"position": 0, "rgb": {"x": 1}}, {"position": 1, "rgb": {"z": 1}}]}},
      "raw_counts": "RAW_COUNTS_UINT32")"));
  ASSERT_TRUE(stops.ok()) << stops.status();
  EXPECT_EQ(stops->point_run()->color.mode, ColorMode::kMap);
  EXPECT_EQ(stops->point_run()->color.blend, 0.5);
  EXPECT_FALSE(stops->density.palette.is_sine());
  EXPECT_TRUE(stops->density.address_grid);
  EXPECT_EQ(stops->density.raw_counts, RawCounts::kInteger);

  auto bad = Convert(SpecWith(map, "", R"(, "color": {"palette": {"stops": [
        {"position": 0.7}, {"position": 0.2}]}})"));
  EXPECT_THAT(std::string(bad.status().message()),
              HasSubstr("chaos_game.color.palette.stops[1].position"));
  auto blend = Convert(SpecWith(map, "", R"(, "color": {"blend": 1.5})"));
  EXPECT_THAT(std::string(blend.status().message()), HasSubstr("chaos_game.color.blend"));
}

TEST(ChaosSpec, MemoryLimitRefusesTheJobBeforeItAllocates) {
  const std::string map = R"({"steps": [{"scale": {"uniform": 0.4}}]})";
  spec::Limits limits;
  limits.max_memory_bytes = uint64_t{6} << 30;
  // Eight half-size copies fill the [-2, 2]^3 box: 2^33 steps touch every
  // tile of two 1024^3 counter grids (2 x 4 GiB), as the pilot run confirms.
  std::string octants = R"({"name": "t", "grid": {"resolution": [1024],
      "bounds_min": {"x": -2, "y": -2, "z": -2}, "bounds_max": {"x": 2, "y": 2, "z": 2}},
      "chaos_game": {"iterations": "8589934592", "ifs": {"maps": [)";
  for (int i = 0; i < 8; ++i)
    octants += absl::StrCat(i ? "," : "", R"({"steps": [{"translate": {"x": )",
                            i & 1 ? 1 : -1, R"(, "y": )", i & 2 ? 1 : -1, R"(, "z": )",
                            i & 4 ? 1 : -1, R"(}}, {"scale": {"uniform": 0.5}}]})");
  octants += "]}}}";
  ASSERT_TRUE(Convert(octants, limits).ok()) << "ConvertSpec prices no memory";
  auto big = Admit(octants, limits);
  EXPECT_EQ(big.status().code(), absl::StatusCode::kResourceExhausted) << big.status();
  EXPECT_THAT(std::string(big.status().message()), HasSubstr("the chaos game needs up to"));
  EXPECT_THAT(std::string(big.status().message()), HasSubstr("measured by a pilot run"));
  // Few steps touch few tiles: the same grid fits.
  auto few = Admit(SpecWith(map, "", "", 1024, 20'000), limits);
  ASSERT_TRUE(few.ok()) << few.status();
  EXPECT_GT(few->estimated_bytes, 0u);
  // A small attractor reaches few tiles however long it runs: these maps
  // keep every point in a ball of radius ~0.5 inside the [-2, 2]^3 grid.
  // (The converter adds its own worst case for the output grid, 4 GiB.)
  auto small = Admit(SpecWith(map, "", "", 1024, uint64_t{1} << 33), limits);
  ASSERT_TRUE(small.ok()) << small.status();
  EXPECT_LT(small->estimated_bytes, uint64_t{5} << 30);
}

TEST(ChaosSpec, ThinAttractorAt2048FitsTheDefaultLimit) {
  // The geometric bound of the tetrahedron at 2048^3 is tens of GiB; the
  // pilot run sees that it touches a few percent of the tiles.
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/sierpinski_tetrahedron.json"));
  ASSERT_TRUE(spec.ok()) << spec.status();
  spec->mutable_grid()->set_resolution(0, 2048);
  spec->mutable_chaos_game()->set_iterations(100'000'000);
  const spec::Limits limits;  // 16 GiB
  auto job = spec::ConvertSpec(*spec, limits);
  ASSERT_TRUE(job.ok()) << job.status();
  auto memory = server::AdmitMemory(*job, limits, 2);
  ASSERT_TRUE(memory.ok()) << memory.status();
  EXPECT_LT(memory->estimated_bytes, uint64_t{8} << 30);
  EXPECT_GT(memory->pilot_samples, 0u) << "the geometric bound alone is above the limit";
}

TEST(ChaosSpec, NonFiniteMapsAreReportedNotFatal) {
  // A map that overflows to infinity every time it is chosen (magnitudes
  // beyond 1e12 are refused at submit; the exponential of 1e12 overflows).
  const std::string map = R"({"steps": [{"scale": {"uniform": 1e12}}],
      "variations": [{"name": "exponential"}], "probability": 0.2})";
  std::string json = SpecWith(map, "", "", 16, 300000);
  v1::JobSpec spec = Parse(json);
  spec.mutable_chaos_game()->mutable_ifs()->mutable_maps(0)->set_probability(0.8);
  spec.mutable_chaos_game()->mutable_ifs()->set_allow_expanding(true);
  auto job = spec::ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  EXPECT_GT(ctx.stats["reseeded"], 1000u);
  bool warned = false;
  for (const auto& w : ctx.warnings) warned |= w.find("bad-point rate") != std::string::npos;
  EXPECT_TRUE(warned);
  auto vol = ReadVdbFile(ctx.result());
  ASSERT_TRUE(vol.ok());
  EXPECT_GT(std::get<int64_t>(*vol->Find("nimbus_reseeded")), 1000);
}

TEST(ChaosSpec, ConvergenceStopsEarlyAndSaysWhy) {
  const std::string map = R"({"steps": [{"translate": {"y": 0.5}}, {"scale": {"uniform": 0.5}}]})";
  auto job = Convert(SpecWith(map, "", R"(, "convergence": {"tolerance": 0.01,
      "check_every": "2097152"})", 128, uint64_t{1} << 32));
  ASSERT_TRUE(job.ok()) << job.status();
  testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  auto vol = ReadVdbFile(ctx.result());
  ASSERT_TRUE(vol.ok());
  EXPECT_EQ(std::get<std::string>(*vol->Find("nimbus_stop_reason")), "converged");
  EXPECT_LT(std::get<int64_t>(*vol->Find("nimbus_iterations")), int64_t{1} << 32);
  EXPECT_LT(std::get<double>(*vol->Find("nimbus_convergence_change")), 0.01);
  EXPECT_GT(ctx.stats["peak_memory_bytes"], 0u);

  // Without convergence the job runs its budget.
  auto full = Convert(SpecWith(map, "", "", 32, 3'000'000));
  ASSERT_TRUE(full.ok());
  testing::FakeJobContext ctx2;
  ASSERT_TRUE(server::RunJobPlan(*full, ctx2).ok());
  auto vol2 = ReadVdbFile(ctx2.result());
  ASSERT_TRUE(vol2.ok());
  EXPECT_EQ(std::get<std::string>(*vol2->Find("nimbus_stop_reason")), "iterations");
}

// Exact counts go to a further file; the result keeps only float grids,
// which every reader (pyopenvdb, Blender) opens.
TEST(ChaosSpec, IntegerCountsGoToAFileOfTheirOwn) {
  const std::string map = R"({"steps": [{"translate": {"y": 0.5}}, {"scale": {"uniform": 0.5}}]})";
  v1::JobSpec spec = Parse(SpecWith(map, "", R"(, "raw_counts": "RAW_COUNTS_UINT32")", 16, 300000));
  spec.set_name("exact");
  auto job = spec::ConvertSpec(spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  auto floats = ReadVdbFile(ctx.result(), "counts");
  ASSERT_TRUE(floats.ok()) << floats.status();
  const auto side = server::ExtraFilesDir(ctx.result()) / "exact.counts.vdb";
  auto exact = ReadIntegerCountsVdb(side, job->frame.resolution);
  ASSERT_TRUE(exact.ok()) << exact.status();
  EXPECT_FALSE(ReadIntegerCountsVdb(ctx.result(), job->frame.resolution).ok());
  int64_t total = 0;
  for (size_t i = 0; i < exact->size(); ++i) {
    EXPECT_EQ(double((*exact)[i]), double(floats->values[i])) << i;
    total += (*exact)[i];
  }
  EXPECT_EQ(total, int64_t(300000 - ctx.stats["outside"]));
}

TEST(ChaosSpec, ColourJobWritesCdAddressAndCounts) {
  const std::string map = R"({"steps": [{"translate": {"y": 0.5}}, {"scale": {"uniform": 0.5}}]})";
  auto job = Convert(SpecWith(map, R"(, "arcs": {"angle_per_unit": 0.4, "amplitude": 0.05,
      "frequency": 0.3})", R"(, "color": {"address_grid": true}, "raw_counts": "RAW_COUNTS_FLOAT")"));
  ASSERT_TRUE(job.ok()) << job.status();
  testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  auto cd = ReadVec3VdbFile(ctx.result());
  ASSERT_TRUE(cd.ok()) << cd.status();
  auto address = ReadVdbFile(ctx.result(), "address");
  ASSERT_TRUE(address.ok()) << address.status();
  auto counts = ReadVdbFile(ctx.result(), "counts");
  ASSERT_TRUE(counts.ok()) << counts.status();
  double total = 0;
  for (float c : counts->values) total += c;
  auto density = ReadVdbFile(ctx.result());
  ASSERT_TRUE(density.ok());
  EXPECT_EQ(int64_t(total), std::get<int64_t>(*density->Find("nimbus_total_count")));
  for (float a : address->values) {
    EXPECT_GE(a, 0.f);
    EXPECT_LE(a, 1.f);
  }
}

TEST(ChaosSpec, SplatIsRecordedAndScalesCounts) {
  const std::string map = R"({"steps": [{"translate": {"y": 0.5}}, {"scale": {"uniform": 0.5}}]})";
  auto job = Convert(SpecWith(map, "", R"(, "splat": true, "raw_counts": "RAW_COUNTS_UINT32")"));
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_TRUE(job->point_run()->splat);
  testing::FakeJobContext ctx;
  ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok());
  auto density = ReadVdbFile(ctx.result());
  ASSERT_TRUE(density.ok());
  EXPECT_EQ(std::get<int64_t>(*density->Find("nimbus_count_scale")), 64);
  const int64_t inside = std::get<int64_t>(*density->Find("nimbus_iterations")) -
                         std::get<int64_t>(*density->Find("nimbus_outside"));
  EXPECT_EQ(std::get<int64_t>(*density->Find("nimbus_total_count")), 64 * inside);
}

// The colour examples, shrunk to a quick run: they stay mostly inside their
// bounds, rarely go non-finite and write Cd.
// FNV-1a over a volume's float bits: pins a result exactly without
// depending on the file format's bytes.
uint64_t ValuesHash(const std::vector<float>& values) {
  uint64_t h = 1469598103934665603ull;
  for (float v : values) {
    uint32_t bits;
    std::memcpy(&bits, &v, 4);
    h = (h ^ bits) * 1099511628211ull;
  }
  return h;
}

// The colour examples at a small size: every plotted point is counted, the
// colours spread over the palette, and the density is pinned bit for bit.
TEST(ChaosSpec, ColourExamplesRunCleanly) {
  struct Case {
    const char* name;
    uint64_t density_hash;
    size_t min_colours;
  };
  // flame_cloud re-pinned when the planar variations took flam3's angle
  // (was 0x54f3ea19950611a5), and again when flames went to 64 walkers per
  // chunk with a fixed number of words per step (was 0xc9055a178d0c3fbc);
  // at this size the scalar, AVX2 and AVX-512 flame kernels happen to give
  // the same values (NIMBUS_SIMD=scalar, avx2).
  for (const Case& c : {Case{"examples/flame_cloud.json", 0xa34fb2d5cad2dd58ull, 200},
                        Case{"examples/arcs_post.json", 0x9623f0ec0d35b1daull, 100}}) {
    auto spec = spec::LoadSpecFile(testing::SourcePath(c.name));
    ASSERT_TRUE(spec.ok()) << c.name << ": " << spec.status();
    spec->mutable_chaos_game()->set_iterations(3'000'000);
    auto& res = *spec->mutable_grid()->mutable_resolution();
    for (int i = 0; i < res.size(); ++i) res[i] = std::max(8, res[i] / 8);
    auto job = spec::ConvertSpec(*spec, {});
    ASSERT_TRUE(job.ok()) << c.name << ": " << job.status();
    testing::FakeJobContext ctx;
    ASSERT_TRUE(server::RunJobPlan(*job, ctx).ok()) << c.name;
    EXPECT_TRUE(ctx.warnings.empty()) << c.name << ": " << ctx.warnings.front();
    EXPECT_LT(ctx.stats["outside"], 3'000'000u / 10) << c.name;
    auto density = ReadVdbFile(ctx.result());
    ASSERT_TRUE(density.ok()) << c.name << ": " << density.status();
    // Every point that landed in the grid is counted once.
    const MetaValue* total = density->Find("nimbus_total_count");
    ASSERT_NE(total, nullptr);
    EXPECT_EQ(std::get<int64_t>(*total), int64_t(3'000'000 - ctx.stats["outside"])) << c.name;
    EXPECT_EQ(ValuesHash(density->values), c.density_hash) << c.name << std::hex << " 0x"
                                                           << ValuesHash(density->values);
    // Address colouring spreads over the palette: many distinct colours,
    // each within the palette's bounds, on exactly the dense voxels.
    auto cd = ReadVec3VdbFile(ctx.result());
    ASSERT_TRUE(cd.ok()) << c.name << ": " << cd.status();
    const Vec3 lo = job->density.palette.MinColor(), hi = job->density.palette.MaxColor();
    std::set<std::tuple<int, int, int>> colours;
    for (size_t i = 0; i < cd->values.size(); ++i) {
      ASSERT_EQ(bool(cd->active[i]), density->values[i] > 0) << c.name << " voxel " << i;
      if (!cd->active[i]) continue;
      const Vec3 v = cd->values[i];
      for (int a = 0; a < 3; ++a) {
        ASSERT_GE(v[a], lo[a] - 1e-5) << c.name;
        ASSERT_LE(v[a], hi[a] + 1e-5) << c.name;
      }
      colours.insert({int(v.x * 255), int(v.y * 255), int(v.z * 255)});
    }
    EXPECT_GE(colours.size(), c.min_colours) << c.name;
  }
}

TEST(ChaosSpec, FernVolumeExampleIsTheBenchmarkedAttractor) {
  auto spec = spec::LoadSpecFile(testing::SourcePath("examples/fern_volume.json"));
  ASSERT_TRUE(spec.ok()) << spec.status();
  auto job = spec::ConvertSpec(*spec, {});
  ASSERT_TRUE(job.ok()) << job.status();
  const ChaosGameParams ref = FernVolumeParams(1024, 1);
  EXPECT_EQ(job->frame.resolution.x, 1024);
  EXPECT_EQ(job->frame.bounds.min, ref.frame.bounds.min);
  EXPECT_EQ(job->frame.bounds.max, ref.frame.bounds.max);
  ASSERT_EQ(job->point_run()->ifs.maps.size(), ref.ifs.maps.size());
  for (size_t i = 0; i < ref.ifs.maps.size(); ++i) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c)
        EXPECT_NEAR(job->point_run()->ifs.maps[i].pre.m[r][c], ref.ifs.maps[i].pre.m[r][c], 1e-12);
    EXPECT_NEAR(job->point_run()->ifs.probabilities[i], ref.ifs.probabilities[i], 1e-12);
  }
  // Volume-filling: the maps' volume factors sum above 1.
  double volume = 0;
  for (const PointMap& m : ref.ifs.maps) volume += std::fabs(m.pre.Determinant());
  EXPECT_GT(volume, 1.0);
}

}  // namespace
}  // namespace nimbus
