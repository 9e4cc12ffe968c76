// nimbus import-flame: flam3 genomes become specs that the server accepts and
// that draw what flam3-render draws (checked against flam3-render itself,
// installed by scripts/install_deps.sh; skipped, saying so, where absent).
#include "client/flame_import.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <sstream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "core/chaos/chaos_game.h"
#include "proto/spec_convert.h"
#include "tests/support/flam3_oracle.h"

namespace nimbus::client {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

std::string Flame(const std::string& body, const std::string& attrs = "") {
  return absl::StrCat("<flame name=\"t\" size=\"200 100\" center=\"1 2\" scale=\"50\" ",
                      "quality=\"10\" ", attrs, ">\n", body, "</flame>\n");
}

std::vector<double> Values(const v1::Step& s) {
  return {s.matrix().values().begin(), s.matrix().values().end()};
}

TEST(FlameImport, AffineXformsAreConjugatedIntoTheMirroredPlane) {
  // x' = 0.5x + 0.2y + 0.3, y' = 0.1x + 0.6y - 0.4 ("a d b e c f").
  auto got = ImportFlame(Flame("<xform weight=\"2\" color=\"0.25\" linear=\"1\" "
                               "coefs=\"0.5 0.1 0.2 0.6 0.3 -0.4\"/>\n"),
                         {});
  ASSERT_TRUE(got.ok()) << got.status();
  const v1::Map& m = got->spec.chaos_game().ifs().maps(0);
  // With y mirrored: x' = 0.5x - 0.2y + 0.3, y' = -0.1x + 0.6y + 0.4.
  EXPECT_THAT(Values(m.steps(0)), ElementsAre(0.5, -0.2, 0, 0.3, -0.1, 0.6, 0, 0.4, 0, 0, 0, 0));
  EXPECT_EQ(m.variations_size(), 0);  // linear alone stays on the affine fast path
  EXPECT_EQ(m.probability(), 2);
  EXPECT_EQ(m.color(), 0.25);
  EXPECT_EQ(got->spec.chaos_game().ifs().probability_mode(), v1::PROBABILITY_MODE_EXPLICIT);
}

TEST(FlameImport, NonlinearXformsKeepTheirVariationsBetweenMirrors) {
  auto got = ImportFlame(Flame("<xform weight=\"1\" color=\"0\" swirl=\"0.7\" julia=\"0.3\" "
                               "coefs=\"1 0 0 1 0.5 0\" post=\"0.5 0 0 0.5 0 0.25\"/>\n"),
                         {});
  ASSERT_TRUE(got.ok()) << got.status();
  const v1::Map& m = got->spec.chaos_game().ifs().maps(0);
  ASSERT_EQ(m.variations_size(), 2);
  EXPECT_EQ(m.variations(0).name(), "julia");  // attributes come in name order
  EXPECT_EQ(m.variations(0).weight(), 0.3);
  EXPECT_EQ(m.variations(1).name(), "swirl");
  // pre o mirror, then mirror o post.
  EXPECT_THAT(Values(m.steps(0)), ElementsAre(1, 0, 0, 0.5, 0, -1, 0, 0, 0, 0, 0, 0));
  EXPECT_THAT(Values(m.post(0)), ElementsAre(0.5, 0, 0, 0, 0, -0.5, 0, -0.25, 0, 0, 0, 0));
}

TEST(FlameImport, CameraBecomesTheGrid) {
  auto got = ImportFlame(Flame("<xform weight=\"1\" linear=\"1\" coefs=\"0.5 0 0 0.5 0 0\"/>\n"),
                         {});
  ASSERT_TRUE(got.ok()) << got.status();
  const v1::Grid& g = got->spec.grid();
  EXPECT_THAT(g.resolution(), ElementsAre(200, 100, 1));
  // 50 pixels per unit around (1, 2), mirrored to (1, -2).
  EXPECT_EQ(g.bounds_min().x(), -1);
  EXPECT_EQ(g.bounds_max().x(), 3);
  EXPECT_EQ(g.bounds_min().y(), -3);
  EXPECT_EQ(g.bounds_max().y(), -1);
  EXPECT_EQ(got->spec.chaos_game().iterations(), 10u * 200 * 100);  // quality x pixels
  EXPECT_EQ(got->spec.name(), "t");
  EXPECT_EQ(got->spec.output().density_mapping(), v1::DENSITY_MAPPING_LOG);
}

TEST(FlameImport, PictureOptionAsksForFlam3sPicture) {
  FlameImportOptions options;
  options.picture = true;
  auto got = ImportFlame(
      Flame("<xform weight=\"1\" linear=\"1\" coefs=\"0.5 0 0 0.5 0 0\"/>\n"), options);
  ASSERT_TRUE(got.ok()) << got.status();
  const v1::ImageOutput& image = got->spec.image();
  EXPECT_EQ(image.width(), 200);
  EXPECT_EQ(image.height(), 100);
  EXPECT_EQ(image.axis(), v1::PROJECTION_AXIS_Z);
  EXPECT_EQ(image.look().tone_mapping(), v1::TONE_MAPPING_LOG);
  EXPECT_TRUE(image.image_only());
  auto plan = spec::ConvertSpec(got->spec, spec::Limits{});
  EXPECT_TRUE(plan.ok()) << plan.status();
}

TEST(FlameImport, PalettesAndColourSpeed) {
  std::string colors;
  for (int i = 0; i < 256; ++i) colors += absl::StrCat("<color index=\"", i, "\" rgb=\"", i,
                                                       " 0 255\"/>\n");
  auto got = ImportFlame(
      Flame("<xform weight=\"1\" color=\"1\" symmetry=\"0.5\" linear=\"1\" "
            "coefs=\"0.5 0 0 0.5 0 0\"/>\n" + colors),
      {});
  ASSERT_TRUE(got.ok()) << got.status();
  const v1::ChaosColor& c = got->spec.chaos_game().color();
  EXPECT_EQ(c.mode(), v1::COLOR_MODE_MAP);
  EXPECT_EQ(c.blend(), 0.25);  // flam3's colour speed (1 - symmetry) / 2
  ASSERT_EQ(c.palette().stops_size(), 256);
  EXPECT_EQ(c.palette().stops(255).position(), 1);
  EXPECT_DOUBLE_EQ(c.palette().stops(51).rgb().x(), 0.2);
  EXPECT_EQ(c.palette().stops(51).rgb().z(), 1);

  auto hex = ImportFlame(Flame("<xform weight=\"1\" linear=\"1\" coefs=\"0.5 0 0 0.5 0 0\"/>\n"
                               "<palette count=\"2\" format=\"RGB\">\n FF0000\n 0000ff\n"
                               "</palette>\n"),
                         {});
  ASSERT_TRUE(hex.ok()) << hex.status();
  const v1::Palette& p = hex->spec.chaos_game().color().palette();
  ASSERT_EQ(p.stops_size(), 2);
  EXPECT_EQ(p.stops(0).rgb().x(), 1);
  EXPECT_EQ(p.stops(1).rgb().z(), 1);
}

TEST(FlameImport, FinalXformAndWarnings) {
  auto got = ImportFlame(Flame("<xform weight=\"1\" linear=\"1\" coefs=\"0.5 0 0 0.5 0 0\" "
                               "opacity=\"0.5\" frobnicate=\"3\"/>\n"
                               "<xform weight=\"0\" linear=\"1\" coefs=\"0.5 0 0 0.5 1 0\"/>\n"
                               "<finalxform color=\"0\" symmetry=\"1\" spherical=\"1\" "
                               "coefs=\"1 0 0 1 0 0\"/>\n",
                               "hue=\"0.2\""),
                         {});
  ASSERT_TRUE(got.ok()) << got.status();
  const v1::Ifs& ifs = got->spec.chaos_game().ifs();
  EXPECT_EQ(ifs.maps_size(), 1);  // the weight-0 xform is never chosen
  ASSERT_TRUE(ifs.has_final());
  EXPECT_EQ(ifs.final().variations(0).name(), "spherical");
  const std::string all = absl::StrJoin(got->warnings, "\n");
  EXPECT_THAT(all, HasSubstr("<xform> #1: ignored attributes frobnicate"));
  EXPECT_THAT(all, HasSubstr("opacity 0.5"));
  EXPECT_THAT(all, HasSubstr("<xform> #2: weight 0"));
  EXPECT_THAT(all, HasSubstr("hue"));
  EXPECT_THAT(all, HasSubstr("no palette"));
}

TEST(FlameImport, ImportedSpecsPassTheServersConverter) {
  auto got = ImportFlame(Flame("<xform weight=\"1\" color=\"0\" swirl=\"1\" "
                               "coefs=\"0.6 0.2 -0.2 0.6 0.1 0.1\"/>\n"
                               "<xform weight=\"1\" color=\"1\" linear=\"1\" "
                               "coefs=\"0.5 0 0 0.5 0.4 -0.3\"/>\n"),
                         {});
  ASSERT_TRUE(got.ok()) << got.status();
  auto plan = spec::ConvertSpec(got->spec, spec::Limits{});
  EXPECT_TRUE(plan.ok()) << plan.status();
}

// flam3's xform (coefs and post given as "a d b e c f") maps a point by
// x' = a x + b y + c, y' = d x + e y + f. A linear xform with a post is
// post(pre(p)): pre (0.5, 0, 0, 0.5, 0.1, -0.4) gives (0.5x + 0.1,
// 0.5y - 0.4); post (0, 1, -1, 0, 0.3, 0.2) then gives (-0.5y + 0.7,
// 0.5x + 0.3). In Nimbus's plane (y mirrored, Y = -y) that is
// X' = 0.5Y + 0.7, Y' = -0.5X - 0.3, one affine step.
TEST(FlameImport, LinearXformWithPostIsPostAfterPre) {
  auto got = ImportFlame(Flame("<xform weight=\"1\" color=\"0\" linear=\"1\" "
                               "coefs=\"0.5 0 0 0.5 0.1 -0.4\" post=\"0 1 -1 0 0.3 0.2\"/>\n"),
                         {});
  ASSERT_TRUE(got.ok()) << got.status();
  const v1::Map& m = got->spec.chaos_game().ifs().maps(0);
  EXPECT_EQ(m.variations_size(), 0);
  EXPECT_EQ(m.post_size(), 0);
  ASSERT_EQ(m.steps_size(), 1);
  const std::vector<double> want = {0, 0.5, 0, 0.7, -0.5, 0, 0, -0.3, 0, 0, 0, 0};
  const std::vector<double> got_values = Values(m.steps(0));
  ASSERT_EQ(got_values.size(), want.size());
  for (size_t i = 0; i < want.size(); ++i) EXPECT_NEAR(got_values[i], want[i], 1e-12) << i;
}

// flam3's color_speed is the weight of the xform's colour in the blend
// c' = (1 - s) c + s colour, given directly; without it symmetry gives
// (1 - symmetry) / 2, so 0.5 by default.
TEST(FlameImport, ColorSpeedIsTheBlend) {
  auto got = ImportFlame(Flame("<xform weight=\"1\" color=\"0.5\" color_speed=\"0.3\" "
                               "linear=\"1\" coefs=\"0.5 0 0 0.5 0 0\"/>\n"
                               "<xform weight=\"1\" color=\"1\" color_speed=\"0.3\" "
                               "linear=\"1\" coefs=\"0.5 0 0 0.5 0.5 0\"/>\n"),
                         {});
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_DOUBLE_EQ(got->spec.chaos_game().color().blend(), 0.3);
  auto plan = spec::ConvertSpec(got->spec, spec::Limits{});
  ASSERT_TRUE(plan.ok()) << plan.status();
  ASSERT_NE(plan->point_run(), nullptr);
  EXPECT_DOUBLE_EQ(plan->point_run()->color.blend, 0.3);
  auto plain = ImportFlame(
      Flame("<xform weight=\"1\" color=\"0.5\" linear=\"1\" coefs=\"0.5 0 0 0.5 0 0\"/>\n"), {});
  ASSERT_TRUE(plain.ok()) << plain.status();
  EXPECT_DOUBLE_EQ(plain->spec.chaos_game().color().blend(), 0.5);
}

struct BadCase {
  std::string xml, message;
};

TEST(FlameImport, BadGenomesAreRefusedNamingWhatIsWrong) {
  const std::string ok_xform = "<xform weight=\"1\" linear=\"1\" coefs=\"0.5 0 0 0.5 0 0\"/>\n";
  const std::vector<BadCase> cases = {
      {"<flame size=\"10 10\"", "line 1: not XML"},
      {"<flames></flames>", "no <flame> element"},
      {Flame(ok_xform + "<xform weight=\"1\" rings=\"0.5\" coefs=\"1 0 0 1 0 0\"/>\n"),
       "line 3, <xform> #2, attribute rings: this flam3 variation is not supported"},
      {Flame("<xform weight=\"1\" linear=\"1\" coefs=\"1 0 0 1 0\"/>\n"),
       "<xform> #1, attribute coefs: needs 6 numbers, got 5"},
      {Flame("<xform weight=\"1\" linear=\"1\" coefs=\"1 0 0 1 0 nan\"/>\n"),
       "attribute coefs: 'nan' is not a finite number"},
      {Flame("<xform weight=\"1\" linear=\"1\" chaos=\"1 0\" coefs=\"1 0 0 1 0 0\"/>\n"),
       "attribute chaos: xaos"},
      {Flame("<xform weight=\"1\" linear=\"1\" color=\"2\" coefs=\"1 0 0 1 0 0\"/>\n"),
       "attribute color: must be in [0, 1]"},
      {Flame("<xform weight=\"0\" linear=\"1\" coefs=\"1 0 0 1 0 0\"/>\n"),
       "no <xform> with weight > 0"},
      {"<flame size=\"100000 10\" scale=\"1\">" + ok_xform + "</flame>",
       "attribute size: needs two whole numbers in [1, 65536]"},
      {"<flame size=\"10 10\">" + ok_xform + "</flame>", "attribute scale: needs a positive"},
      {Flame(ok_xform, "zoom=\"1000000\""), "attribute zoom: scale 50 times 2^zoom"},
      {Flame(ok_xform, "zoom=\"-1000000\""), "attribute zoom: scale 50 times 2^zoom"},
      {"<flame size=\"10 10\" scale=\"1e-320\">" + ok_xform + "</flame>",
       "attribute scale: scale"},
      {Flame(ok_xform + "<color index=\"300\" rgb=\"1 2 3\"/>\n"), "attribute index"},
      {Flame(ok_xform + "<palette count=\"1\">12345</palette>\n"), "6 hex digits"},
  };
  for (const BadCase& c : cases) {
    SCOPED_TRACE(c.xml);
    auto got = ImportFlame(c.xml, {});
    ASSERT_FALSE(got.ok());
    EXPECT_THAT(std::string(got.status().message()), HasSubstr(c.message));
  }
}

TEST(FlameImport, FilesWithSeveralGenomesChooseByNameOrIndex) {
  const std::string two =
      "<flames>\n"
      "<flame name=\"a\" size=\"10 10\" scale=\"5\">"
      "<xform weight=\"1\" linear=\"1\" coefs=\"0.5 0 0 0.5 0 0\"/></flame>\n"
      "<flame name=\"b\" size=\"20 10\" scale=\"5\">"
      "<xform weight=\"1\" linear=\"1\" coefs=\"0.5 0 0 0.5 0 0\"/></flame>\n"
      "</flames>\n";
  auto none = ImportFlame(two, {});
  ASSERT_FALSE(none.ok());
  EXPECT_THAT(std::string(none.status().message()), HasSubstr("holds 2 genomes"));
  FlameImportOptions by_name;
  by_name.genome = "b";
  auto b = ImportFlame(two, by_name);
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(b->spec.grid().resolution(0), 20);
  EXPECT_THAT(b->genome_names, ElementsAre("a", "b"));
  FlameImportOptions by_index;
  by_index.genome = "0";
  by_index.iterations = 1234;
  auto a = ImportFlame(two, by_index);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->spec.name(), "a");
  EXPECT_EQ(a->spec.chaos_game().iterations(), 1234u);
  by_index.genome = "7";
  EXPECT_EQ(ImportFlame(two, by_index).status().code(), absl::StatusCode::kNotFound);
}

// --- Against flam3-render --------------------------------------------------

constexpr int kSize = 128;
constexpr int kCell = 4;
// Measured 0.985 to 1.000 on every genome below; the same bar as the
// engine's own variation agreement test.
constexpr double kMinCorrelation = 0.95;

// Two xforms (one with the variation under test), flam3's camera around a
// point off the origin and, in some genomes, a turn, a post and a final.
// `variations` are the first xform's variation attributes.
std::string AgreementGenome(const std::string& variations, double rotate, bool extras) {
  std::ostringstream g;
  g << "<flame name=\"t\" size=\"" << kSize << " " << kSize
    << "\" center=\"0.2 -0.1\" scale=\"" << kSize / 4.4 << "\" rotate=\"" << rotate
    << "\" quality=\"200\" oversample=\"1\" filter=\"0\" supersample=\"1\""
    << " estimator_radius=\"0\" gamma=\"1\" brightness=\"4\" vibrancy=\"1\">\n"
    << "<xform weight=\"0.5\" color=\"0\" " << variations
    << " coefs=\"0.6 0.2 -0.2 0.6 0.1 0.1\"" << (extras ? " post=\"1 0.1 0 0.9 0 0.1\"" : "")
    << "/>\n<xform weight=\"0.5\" color=\"1\" linear=\"1\" coefs=\"0.5 0 0 0.5 0.4 -0.3\"/>\n";
  if (extras) g << "<finalxform color=\"0\" symmetry=\"1\" linear=\"0.8\" swirl=\"0.2\" "
                   "coefs=\"1 0 0 1 0 0\"/>\n";
  for (int i = 0; i < 256; ++i) g << "<color index=\"" << i << "\" rgb=\"255 255 255\"/>\n";
  g << "</flame>\n";
  return g.str();
}

// The imported spec run by the engine, as log(1 + visits) in flam3's pixel
// order: its top row holds the smallest flam3 y, the largest Nimbus y.
std::vector<double> RenderImported(const std::string& genome) {
  auto got = ImportFlame(genome, {});
  EXPECT_TRUE(got.ok()) << got.status();
  if (!got.ok()) return {};
  got->spec.mutable_chaos_game()->set_seed(3);
  auto plan = spec::ConvertSpec(got->spec, spec::Limits{});
  EXPECT_TRUE(plan.ok()) << plan.status();
  if (!plan.ok()) return {};
  ChaosGameParams p = std::get<ChaosGamePlan>(plan->kind).params;
  p.frame = plan->frame;
  p.color = {};  // density only
  auto game = ChaosGame::Create(p, 2);
  EXPECT_TRUE(game.ok()) << game.status();
  EXPECT_TRUE((*game)->Run(nullptr).ok());
  const CountGrid counts = (*game)->TakeCounts();
  std::vector<double> out(size_t(kSize) * kSize);
  for (int row = 0; row < kSize; ++row)
    for (int x = 0; x < kSize; ++x)
      out[size_t(row) * kSize + x] = std::log1p(counts.Get(x, kSize - 1 - row, 0));
  return out;
}

TEST(FlameImportAgreement, ImportedGenomesDrawWhatFlam3Draws) {
  if (!testing::HaveFlam3())
    GTEST_SKIP() << "flam3-render is absent: scripts/install_deps.sh installs it (flam3-utils)";
  char dir_template[] = "/tmp/nimbus_import_XXXXXX";
  const std::string dir = mkdtemp(dir_template);
  struct Case {
    std::string name, variations;
    double rotate;
    bool extras;
  };
  // spherical alone piles most samples into a few filaments, and flam3's
  // clipped tone map then hides the rest (0.86 here, though brighter flam3
  // renders show the same cloud); mixed with linear it is compared fairly.
  std::vector<Case> cases = {{"spherical_linear", "spherical=\"0.5\" linear=\"0.5\"", 0, false},
                             {"julia_turned", "julia=\"1\"", 30, false},
                             {"swirl_turned_post_final", "swirl=\"1\"", -50, true},
                             {"polar_post_final", "polar=\"1\"", 0, true}};
  for (const char* v : {"linear", "sinusoidal", "swirl", "horseshoe", "polar",
                        "handkerchief", "heart", "disc", "spiral", "hyperbolic", "diamond", "ex",
                        "julia", "bent", "fisheye", "exponential", "power", "cylinder",
                        "bubble"})
    cases.push_back({v, absl::StrCat(v, "=\"1\""), 0, false});
  for (const Case& c : cases) {
    const std::string& name = c.name;
    SCOPED_TRACE(name);
    const std::string genome = AgreementGenome(c.variations, c.rotate, c.extras);
    const std::vector<double> flam3 = testing::RenderWithFlam3(genome, dir, name, kSize, kSize);
    ASSERT_EQ(flam3.size(), size_t(kSize) * kSize) << "flam3-render failed";
    const double r = testing::CellCorrelation(flam3, RenderImported(genome), kSize, kSize, kCell);
    std::printf("%-18s log-density correlation %.3f\n", name.c_str(), r);
    EXPECT_GE(r, kMinCorrelation);
  }
  std::system(absl::StrCat("rm -rf ", dir).c_str());
}

}  // namespace
}  // namespace nimbus::client
