#include "client/flame_import.h"

#include <expat.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <map>
#include <optional>
#include <set>

#include "absl/strings/numbers.h"
#include "absl/strings/string_view.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "core/base/status_macros.h"
#include "core/chaos/variations.h"

namespace nimbus::client {
namespace {

using absl::StrCat;

// One XML element as read: enough of a tree for flam3 genomes, which are
// flat lists of <xform>, <finalxform>, <color> and <palette> under <flame>.
struct Element {
  std::string name;
  std::map<std::string, std::string> attrs;
  int line = 0;
  int index = 0;  // among its kind within the genome, from 0
};

struct Genome {
  Element flame;
  std::vector<Element> xforms;
  std::vector<Element> finals;
  std::vector<Element> colors;
  std::vector<Element> others;
  /// A <palette> element, and its hex text.
  std::optional<Element> palette;
  std::string palette_hex;
};

// Guards against absurd files before anything is built from them.
constexpr size_t kMaxGenomes = 100000;
constexpr size_t kMaxXforms = 1000;

struct ParseState {
  XML_Parser parser = nullptr;
  std::vector<Genome> genomes;
  Genome* current = nullptr;
  bool in_palette = false;
  std::string error;
};

Element MakeElement(ParseState& s, const char* name, const char** attrs) {
  Element e;
  e.name = name;
  e.line = int(XML_GetCurrentLineNumber(s.parser));
  for (int i = 0; attrs[i]; i += 2) e.attrs[attrs[i]] = attrs[i + 1];
  return e;
}

void Fail(ParseState& s, std::string message) {
  if (s.error.empty()) s.error = std::move(message);
  XML_StopParser(s.parser, XML_FALSE);
}

void XMLCALL OnStart(void* data, const char* name, const char** attrs) {
  auto& s = *static_cast<ParseState*>(data);
  const std::string tag = name;
  if (tag == "flame") {
    if (s.genomes.size() >= kMaxGenomes) return Fail(s, "more than 100000 genomes");
    s.genomes.emplace_back();
    s.current = &s.genomes.back();
    s.current->flame = MakeElement(s, name, attrs);
    s.current->flame.index = int(s.genomes.size()) - 1;
    return;
  }
  if (!s.current) return;  // <flames> wrappers, comments, unknown roots
  Genome& g = *s.current;
  auto add = [&](std::vector<Element>& to) {
    if (to.size() >= kMaxXforms) return Fail(s, StrCat("more than 1000 <", tag, "> elements"));
    to.push_back(MakeElement(s, name, attrs));
    to.back().index = int(to.size()) - 1;
  };
  if (tag == "xform") return add(g.xforms);
  if (tag == "finalxform") return add(g.finals);
  if (tag == "color") return add(g.colors);
  if (tag == "palette") {
    g.palette = MakeElement(s, name, attrs);
    s.in_palette = true;
    return;
  }
  g.others.push_back(MakeElement(s, name, attrs));
}

void XMLCALL OnEnd(void* data, const char* name) {
  auto& s = *static_cast<ParseState*>(data);
  const std::string tag = name;
  if (tag == "flame") s.current = nullptr;
  if (tag == "palette") s.in_palette = false;
}

void XMLCALL OnText(void* data, const char* text, int len) {
  auto& s = *static_cast<ParseState*>(data);
  if (s.in_palette && s.current) s.current->palette_hex.append(text, size_t(len));
}

absl::StatusOr<std::vector<Genome>> ParseGenomes(std::string_view xml) {
  ParseState s;
  s.parser = XML_ParserCreate(nullptr);
  XML_SetUserData(s.parser, &s);
  XML_SetElementHandler(s.parser, OnStart, OnEnd);
  XML_SetCharacterDataHandler(s.parser, OnText);
  const bool ok = XML_Parse(s.parser, xml.data(), int(xml.size()), XML_TRUE) == XML_STATUS_OK;
  const int line = int(XML_GetCurrentLineNumber(s.parser));
  const char* expat_error = ok ? "" : XML_ErrorString(XML_GetErrorCode(s.parser));
  XML_ParserFree(s.parser);
  if (!s.error.empty()) return absl::InvalidArgumentError(StrCat("line ", line, ": ", s.error));
  if (!ok)
    return absl::InvalidArgumentError(
        StrCat("line ", line, ": not XML: ", expat_error ? expat_error : "?"));
  if (s.genomes.empty()) return absl::InvalidArgumentError("no <flame> element");
  return std::move(s.genomes);
}

std::string Where(const Element& e) {
  if (e.name == "flame") return StrCat("line ", e.line, ", <flame>");
  return StrCat("line ", e.line, ", <", e.name, "> #", e.index + 1);
}

absl::Status Bad(const Element& e, const std::string& attr, const std::string& what) {
  return absl::InvalidArgumentError(StrCat(Where(e), ", attribute ", attr, ": ", what));
}

// The attribute's numbers (whitespace separated), `count` of them when
// count > 0; `fallback` when the attribute is absent.
absl::StatusOr<std::vector<double>> Numbers(const Element& e, const std::string& attr,
                                            size_t count, std::vector<double> fallback = {}) {
  auto it = e.attrs.find(attr);
  if (it == e.attrs.end()) {
    if (fallback.empty()) return Bad(e, attr, "missing");
    return fallback;
  }
  std::vector<double> out;
  for (absl::string_view w : absl::StrSplit(it->second, ' ', absl::SkipWhitespace())) {
    double v;
    if (!absl::SimpleAtod(w, &v) || !std::isfinite(v))
      return Bad(e, attr, StrCat("'", w, "' is not a finite number"));
    out.push_back(v);
  }
  if (count > 0 && out.size() != count)
    return Bad(e, attr, StrCat("needs ", count, " numbers, got ", out.size()));
  if (out.empty()) return Bad(e, attr, "empty");
  return out;
}

absl::StatusOr<double> Number(const Element& e, const std::string& attr, double fallback) {
  NIMBUS_ASSIGN_OR_RETURN(std::vector<double> v, Numbers(e, attr, 0, {fallback}));
  return v[0];  // flam3's old two-number colours keep the first
}

// A 2D affine map x' = m[0] x + m[1] y + m[2], y' = m[3] x + m[4] y + m[5].
using Affine2 = std::array<double, 6>;

Affine2 Compose(const Affine2& a, const Affine2& b) {  // a after b
  return {a[0] * b[0] + a[1] * b[3], a[0] * b[1] + a[1] * b[4], a[0] * b[2] + a[1] * b[5] + a[2],
          a[3] * b[0] + a[4] * b[3], a[3] * b[1] + a[4] * b[4], a[3] * b[2] + a[4] * b[5] + a[5]};
}

constexpr Affine2 kIdentity = {1, 0, 0, 0, 1, 0};

// flam3 writes coefficients as "a d b e c f" for x' = a x + b y + c,
// y' = d x + e y + f.
absl::StatusOr<Affine2> Coefs(const Element& e, const std::string& attr, bool required) {
  if (!required && !e.attrs.count(attr)) return kIdentity;
  NIMBUS_ASSIGN_OR_RETURN(std::vector<double> c, Numbers(e, attr, 6));
  return Affine2{c[0], c[2], c[4], c[1], c[3], c[5]};
}

void SetMatrix(const Affine2& a, v1::Step* step) {
  auto* v = step->mutable_matrix()->mutable_values();
  for (double x : {a[0], a[1], 0.0, a[2], a[3], a[4], 0.0, a[5], 0.0, 0.0, 0.0, 0.0}) v->Add(x);
}

// Attributes of <xform> that are not variations.
const std::set<std::string>& NonVariationAttrs() {
  static const std::set<std::string> s = {
      "weight",  "color",   "symmetry", "color_speed",      "coefs",           "post",
      "opacity", "animate", "name",     "motion_frequency", "motion_function", "var_color",
      "chaos",   "plotmode"};
  return s;
}

// flam3's variations that Nimbus does not have: naming one with a non-zero
// weight is refused rather than drawn differently.
const std::set<std::string>& OtherFlam3Variations() {
  static const std::set<std::string> s = {
      "cosine",       "rings",     "fan",        "blob",       "pdj",       "fan2",
      "rings2",       "eyefish",   "perspective", "julian",    "juliascope", "gaussian_blur",
      "radial_blur",  "pie",       "ngon",       "curl",       "rectangles", "arch",
      "tangent",      "square",    "rays",       "blade",      "secant2",   "twintrian",
      "cross",        "disc2",     "super_shape", "flower",    "conic",     "parabola",
      "bent2",        "bipolar",   "boarders",   "butterfly",  "cell",      "cpow",
      "curve",        "edisc",     "elliptic",   "escher",     "foci",      "lazysusan",
      "loonie",       "pre_blur",  "modulus",    "oscilloscope", "polar2",  "popcorn2",
      "scry",         "separation", "split",     "splits",     "stripes",   "wedge",
      "wedge_julia",  "wedge_sph", "whorl",      "waves2",     "exp",       "log",
      "sin",          "cos",       "tan",        "sec",        "csc",       "cot",
      "sinh",         "cosh",      "tanh",       "sech",       "csch",      "coth",
      "auger",        "flux",      "mobius"};
  return s;
}

struct Camera {
  Affine2 to_nimbus = kIdentity;    // flam3 plane -> Nimbus plane (linear)
  Affine2 from_nimbus = kIdentity;  // its inverse
  int width = 0, height = 0;
  double center_x = 0, center_y = 0, pixels_per_unit = 0;
};

// flam3's pictures put the smallest y in the top row and turn the view by
// `rotate` degrees. Nimbus draws y up, so the genome is carried into a plane
// mirrored in y and turned the other way, where "up" is flam3's top row.
absl::StatusOr<Camera> ReadCamera(const Element& f) {
  Camera c;
  NIMBUS_ASSIGN_OR_RETURN(std::vector<double> size, Numbers(f, "size", 2));
  if (!(size[0] >= 1 && size[0] <= 65536 && size[1] >= 1 && size[1] <= 65536) ||
      size[0] != std::floor(size[0]) || size[1] != std::floor(size[1]))
    return Bad(f, "size", "needs two whole numbers in [1, 65536]");
  c.width = int(size[0]), c.height = int(size[1]);
  NIMBUS_ASSIGN_OR_RETURN(std::vector<double> center, Numbers(f, "center", 2, {0.0, 0.0}));
  NIMBUS_ASSIGN_OR_RETURN(double scale, Number(f, "scale", 0.0));
  NIMBUS_ASSIGN_OR_RETURN(double zoom, Number(f, "zoom", 0.0));
  NIMBUS_ASSIGN_OR_RETURN(double rotate, Number(f, "rotate", 0.0));
  if (!(scale > 0)) return Bad(f, "scale", "needs a positive scale (pixels per unit)");
  // flam3 multiplies the scale by 2^zoom; the product must leave a finite,
  // non-empty view of the picture's size.
  c.pixels_per_unit = scale * std::exp2(zoom);
  const double span = std::max(size[0], size[1]) / c.pixels_per_unit;
  if (!(c.pixels_per_unit > 0 && std::isfinite(c.pixels_per_unit) && std::isfinite(span)))
    return Bad(f, zoom != 0 ? "zoom" : "scale",
               StrCat("scale ", scale, " times 2^zoom (zoom ", zoom, ") gives ", c.pixels_per_unit,
                      " pixels per unit, which leaves no usable view"));
  const double t = rotate * M_PI / 180.0, cs = std::cos(t), sn = std::sin(t);
  // Mirror y after turning by `rotate`; C is its own inverse.
  c.to_nimbus = {cs, -sn, 0, -sn, -cs, 0};
  c.from_nimbus = {cs, -sn, 0, -sn, -cs, 0};
  const Affine2 p = Compose(c.to_nimbus, {1, 0, center[0], 0, 1, center[1]});
  c.center_x = p[2], c.center_y = p[5];
  return c;
}

struct MapColour {
  double color = 0, speed = 0.5;
};

absl::StatusOr<MapColour> ReadColour(const Element& x) {
  MapColour m;
  NIMBUS_ASSIGN_OR_RETURN(m.color, Number(x, "color", 0.0));
  if (!(m.color >= 0 && m.color <= 1)) return Bad(x, "color", "must be in [0, 1]");
  NIMBUS_ASSIGN_OR_RETURN(double symmetry, Number(x, "symmetry", 0.0));
  m.speed = (1 - symmetry) / 2;
  if (x.attrs.count("color_speed")) {
    NIMBUS_ASSIGN_OR_RETURN(m.speed, Number(x, "color_speed", 0.5));
  }
  return m;
}

absl::Status CheckChaos(const Element& x) {
  if (!x.attrs.count("chaos")) return absl::OkStatus();
  NIMBUS_ASSIGN_OR_RETURN(std::vector<double> chaos, Numbers(x, "chaos", 0));
  for (double v : chaos)
    if (v != 1) return Bad(x, "chaos", "xaos (per-xform transition weights) is not supported");
  return absl::OkStatus();
}

// Adds the xform's variations to `map`; unknown attributes go to `ignored`.
absl::Status ReadVariations(const Element& x, v1::Map& map, std::vector<std::string>& ignored) {
  bool only_linear = true;
  for (const auto& [attr, value] : x.attrs) {
    if (NonVariationAttrs().count(attr)) continue;
    // Apophysis writes linear3D for flam3's linear.
    const std::string name = attr == "linear3D" ? "linear" : attr;
    const bool ours = VariationFromName(name).has_value() && name != "polar_doubling";
    if (!ours && !OtherFlam3Variations().count(name)) {
      ignored.push_back(attr);
      continue;
    }
    NIMBUS_ASSIGN_OR_RETURN(double weight, Number(x, attr, 0.0));
    if (weight == 0) continue;
    if (!ours)
      return Bad(x, attr, "this flam3 variation is not supported (docs/variations.md lists ours)");
    auto* v = map.add_variations();
    v->set_name(name);
    v->set_weight(weight);
    only_linear = only_linear && name == "linear" && weight == 1;
  }
  // linear alone with weight 1 is the affine map: keep Nimbus's fast path.
  if (only_linear) map.clear_variations();
  return absl::OkStatus();
}

// flam3 applies a map as post(sum w V(pre p)); in Nimbus's plane the map
// becomes C o map o C^-1, which keeps every variation as flam3 computes it.
absl::Status ReadMap(const Element& x, const Camera& cam, v1::Map& map,
                     std::vector<std::string>& warnings) {
  NIMBUS_ASSIGN_OR_RETURN(Affine2 pre, Coefs(x, "coefs", true));
  NIMBUS_ASSIGN_OR_RETURN(Affine2 post, Coefs(x, "post", false));
  std::vector<std::string> ignored;
  NIMBUS_RETURN_IF_ERROR(ReadVariations(x, map, ignored));
  NIMBUS_RETURN_IF_ERROR(CheckChaos(x));
  if (!ignored.empty())
    warnings.push_back(StrCat(Where(x), ": ignored attributes ", absl::StrJoin(ignored, ", ")));
  NIMBUS_ASSIGN_OR_RETURN(double opacity, Number(x, "opacity", 1.0));
  if (opacity != 1)
    warnings.push_back(StrCat(Where(x), ": opacity ", opacity, " is drawn as 1"));
  for (const v1::Variation& v : map.variations())
    if (v.name() == "waves")
      warnings.push_back(StrCat(Where(x), ": waves reads the matrix, so the mirrored plane "
                                          "changes it; the picture will differ from flam3's"));
  if (map.variations().empty()) {
    SetMatrix(Compose(cam.to_nimbus, Compose(post, Compose(pre, cam.from_nimbus))),
              map.add_steps());
    return absl::OkStatus();
  }
  SetMatrix(Compose(pre, cam.from_nimbus), map.add_steps());
  SetMatrix(Compose(cam.to_nimbus, post), map.add_post());
  return absl::OkStatus();
}

absl::StatusOr<double> ReadXforms(const Genome& g, const Camera& cam, v1::Ifs& ifs,
                                  std::vector<std::string>& warnings) {
  std::set<double> speeds;
  double first_speed = -1;
  for (const Element& x : g.xforms) {
    NIMBUS_ASSIGN_OR_RETURN(double weight, Number(x, "weight", 0.0));
    if (!(weight > 0)) {
      warnings.push_back(StrCat(Where(x), ": weight ", weight, " is never chosen; left out"));
      continue;
    }
    v1::Map& map = *ifs.add_maps();
    map.set_name(StrCat("xform", x.index + 1));
    map.set_probability(weight);
    NIMBUS_ASSIGN_OR_RETURN(MapColour c, ReadColour(x));
    map.set_color(c.color);
    if (first_speed < 0) first_speed = c.speed;
    speeds.insert(c.speed);
    NIMBUS_RETURN_IF_ERROR(ReadMap(x, cam, map, warnings));
  }
  if (ifs.maps().empty())
    return absl::InvalidArgumentError(StrCat(Where(g.flame), ": no <xform> with weight > 0"));
  if (speeds.size() > 1)
    warnings.push_back(StrCat("xforms use different colour speeds; Nimbus blends every map at ",
                              first_speed, " (the first xform's)"));
  return first_speed;
}

absl::Status ReadFinal(const Genome& g, const Camera& cam, v1::Ifs& ifs,
                       std::vector<std::string>& warnings) {
  if (g.finals.empty()) return absl::OkStatus();
  if (g.finals.size() > 1)
    return absl::InvalidArgumentError(StrCat(Where(g.finals[1]), ": a second <finalxform>"));
  const Element& x = g.finals[0];
  NIMBUS_ASSIGN_OR_RETURN(MapColour c, ReadColour(x));
  if (c.speed != 0)
    warnings.push_back(StrCat(Where(x), ": its colour is not applied (Nimbus's final "
                                        "transform moves points only)"));
  v1::Map& map = *ifs.mutable_final();
  map.set_name("final");
  return ReadMap(x, cam, map, warnings);
}

absl::StatusOr<std::array<double, 3>> ColorRgb(const Element& c) {
  NIMBUS_ASSIGN_OR_RETURN(std::vector<double> rgb, Numbers(c, "rgb", 3));
  for (double v : rgb)
    if (!(v >= 0 && v <= 255)) return Bad(c, "rgb", "values must be in [0, 255]");
  return std::array<double, 3>{rgb[0] / 255, rgb[1] / 255, rgb[2] / 255};
}

absl::StatusOr<std::vector<std::array<double, 3>>> HexPalette(const Genome& g) {
  std::string hex;
  for (char ch : g.palette_hex)
    if (!std::isspace(static_cast<unsigned char>(ch))) hex.push_back(ch);
  const Element& el = *g.palette;
  if (hex.size() % 6 != 0 || hex.empty() || hex.size() > 6 * 4096)
    return Bad(el, "(text)", "needs 6 hex digits per colour, up to 4096 colours");
  std::vector<std::array<double, 3>> out;
  for (size_t i = 0; i < hex.size(); i += 6) {
    std::array<double, 3> rgb;
    for (int k = 0; k < 3; ++k) {
      char* end = nullptr;
      const std::string byte = hex.substr(i + 2 * k, 2);
      rgb[k] = double(std::strtol(byte.c_str(), &end, 16)) / 255;
      if (*end) return Bad(el, "(text)", StrCat("'", byte, "' is not hexadecimal"));
    }
    out.push_back(rgb);
  }
  return out;
}

absl::Status ReadPalette(const Genome& g, v1::Palette& palette,
                         std::vector<std::string>& warnings) {
  std::vector<std::array<double, 3>> colours;
  if (g.palette) {
    NIMBUS_ASSIGN_OR_RETURN(colours, HexPalette(g));
  } else if (!g.colors.empty()) {
    std::map<int, std::array<double, 3>> by_index;
    for (const Element& c : g.colors) {
      NIMBUS_ASSIGN_OR_RETURN(double index, Number(c, "index", -1));
      if (!(index >= 0 && index <= 255) || index != std::floor(index))
        return Bad(c, "index", "needs a whole number in [0, 255]");
      NIMBUS_ASSIGN_OR_RETURN(by_index[int(index)], ColorRgb(c));
    }
    for (const auto& [i, rgb] : by_index) colours.push_back(rgb);
    if (by_index.size() != 256 && by_index.size() > 1)
      warnings.push_back(StrCat("the palette has ", by_index.size(), " of 256 colours; the rest "
                                                                     "are interpolated"));
  } else {
    warnings.push_back(g.flame.attrs.count("palette")
                           ? "flam3's built-in palettes are not available: a grey ramp is used"
                           : "no palette: a grey ramp is used");
    colours = {{0, 0, 0}, {1, 1, 1}};
  }
  const size_t n = colours.size();
  for (size_t i = 0; i < n; ++i) {
    auto* stop = palette.add_stops();
    stop->set_position(n == 1 ? 0.0 : double(i) / double(n - 1));
    stop->mutable_rgb()->set_x(colours[i][0]);
    stop->mutable_rgb()->set_y(colours[i][1]);
    stop->mutable_rgb()->set_z(colours[i][2]);
  }
  return absl::OkStatus();
}

std::string JobName(const Genome& g) {
  auto it = g.flame.attrs.find("name");
  std::string name;
  if (it != g.flame.attrs.end())
    for (char ch : it->second.substr(0, 100))
      name.push_back(std::isalnum(static_cast<unsigned char>(ch)) || ch == '-' || ch == '.'
                         ? ch
                         : '_');
  return name.empty() ? "flame" : name;
}

void WarnUnused(const Genome& g, std::vector<std::string>& warnings) {
  for (const Element& e : g.others)
    if (e.name == "symmetry")
      warnings.push_back(StrCat(Where(e), ": <symmetry> is not supported; add the rotated "
                                          "xforms explicitly"));
  // Look settings, reported only where they differ from flam3's defaults.
  const std::pair<const char*, double> looks[] = {
      {"hue", 0}, {"brightness", 4}, {"vibrancy", 1}, {"highlight_power", -1}};
  for (const auto& [attr, fallback] : looks) {
    auto it = g.flame.attrs.find(attr);
    double v;
    if (it == g.flame.attrs.end() || (absl::SimpleAtod(it->second, &v) && v == fallback))
      continue;
    warnings.push_back(StrCat("flame attribute ", attr, "=\"", it->second,
                              "\" is a look setting the volume does not carry"));
  }
}

absl::StatusOr<const Genome*> Choose(const std::vector<Genome>& all, const std::string& want) {
  if (want.empty()) {
    if (all.size() == 1) return &all[0];
    return absl::InvalidArgumentError(
        StrCat("the file holds ", all.size(), " genomes: choose one by name or index"));
  }
  for (const Genome& g : all) {
    auto it = g.flame.attrs.find("name");
    if (it != g.flame.attrs.end() && it->second == want) return &g;
  }
  int index;
  if (absl::SimpleAtoi(want, &index) && index >= 0 && size_t(index) < all.size())
    return &all[size_t(index)];
  return absl::NotFoundError(StrCat("no genome named or numbered '", want, "'"));
}

absl::Status Convert(const Genome& g, const FlameImportOptions& options, FlameImport& out) {
  NIMBUS_ASSIGN_OR_RETURN(Camera cam, ReadCamera(g.flame));
  v1::JobSpec& spec = out.spec;
  spec.set_name(JobName(g));
  auto* grid = spec.mutable_grid();
  grid->add_resolution(cam.width);
  grid->add_resolution(cam.height);
  grid->add_resolution(1);
  const double hw = cam.width / (2 * cam.pixels_per_unit);
  const double hh = cam.height / (2 * cam.pixels_per_unit);
  grid->mutable_bounds_min()->set_x(cam.center_x - hw);
  grid->mutable_bounds_min()->set_y(cam.center_y - hh);
  grid->mutable_bounds_min()->set_z(-0.5);
  grid->mutable_bounds_max()->set_x(cam.center_x + hw);
  grid->mutable_bounds_max()->set_y(cam.center_y + hh);
  grid->mutable_bounds_max()->set_z(0.5);
  v1::ChaosGame& game = *spec.mutable_chaos_game();
  v1::Ifs& ifs = *game.mutable_ifs();
  ifs.set_probability_mode(v1::PROBABILITY_MODE_EXPLICIT);
  // flam3 draws whatever the genome does; contraction is not its rule.
  ifs.set_allow_expanding(true);
  NIMBUS_ASSIGN_OR_RETURN(double speed, ReadXforms(g, cam, ifs, out.warnings));
  NIMBUS_RETURN_IF_ERROR(ReadFinal(g, cam, ifs, out.warnings));
  NIMBUS_ASSIGN_OR_RETURN(double quality, Number(g.flame, "quality", 50.0));
  if (!(quality > 0)) return Bad(g.flame, "quality", "must be positive");
  const double samples = std::ceil(quality * cam.width * cam.height);
  game.set_iterations(options.iterations ? options.iterations
                                         : uint64_t(std::min(samples, 1e15)));
  game.set_seed(options.seed);
  v1::ChaosColor& colour = *game.mutable_color();
  colour.set_mode(v1::COLOR_MODE_MAP);
  if (speed <= 0) {
    out.warnings.push_back("colour speed 0 (symmetry 1) keeps colours fixed; Nimbus needs a "
                           "positive blend, so 0.001 is used");
    speed = 0.001;
  }
  colour.set_blend(std::min(speed, 1.0));
  NIMBUS_RETURN_IF_ERROR(ReadPalette(g, *colour.mutable_palette(), out.warnings));
  // flam3 shows log density; so does the imported volume.
  spec.mutable_output()->set_density_mapping(v1::DENSITY_MAPPING_LOG);
  if (options.picture) {
    // flam3's picture: its size, looking down z with y up (the mirrored
    // plane puts flam3's top row there), log density.
    v1::ImageOutput& image = *spec.mutable_image();
    image.set_width(cam.width);
    image.set_height(cam.height);
    image.set_axis(v1::PROJECTION_AXIS_Z);
    image.set_format(v1::IMAGE_FORMAT_PNG8);
    image.mutable_look()->set_tone_mapping(v1::TONE_MAPPING_LOG);
    image.set_image_only(true);
  }
  WarnUnused(g, out.warnings);
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<FlameImport> ImportFlame(std::string_view xml, const FlameImportOptions& options) {
  NIMBUS_ASSIGN_OR_RETURN(std::vector<Genome> genomes, ParseGenomes(xml));
  FlameImport out;
  for (const Genome& g : genomes) {
    auto it = g.flame.attrs.find("name");
    out.genome_names.push_back(it != g.flame.attrs.end() ? it->second
                                                         : StrCat("#", g.flame.index));
  }
  NIMBUS_ASSIGN_OR_RETURN(const Genome* g, Choose(genomes, options.genome));
  absl::Status s = Convert(*g, options, out);
  if (!s.ok() && genomes.size() > 1)
    return absl::Status(s.code(), StrCat("genome '", out.genome_names[size_t(g->flame.index)],
                                         "': ", s.message()));
  NIMBUS_RETURN_IF_ERROR(s);
  return out;
}

}  // namespace nimbus::client
