#include "tests/support/decoded_content.h"

#include <openvdb/openvdb.h>
#include <png.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <mutex>
#include <sstream>
#include <string_view>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/sha256.h"

namespace nimbus::testing {

namespace {

void Put(Sha256& h, const void* p, size_t n) {
  h.Update(std::string_view(static_cast<const char*>(p), n));
}
template <typename T>
void PutValue(Sha256& h, const T& v) {
  Put(h, &v, sizeof(T));
}
void PutString(Sha256& h, const std::string& s) {
  PutValue(h, uint64_t(s.size()));
  h.Update(s);
}

void PutMetadata(Sha256& h, const openvdb::GridBase& grid) {
  for (auto it = grid.beginMeta(); it != grid.endMeta(); ++it) {
    if (it->first.rfind("file_", 0) == 0) continue;  // the writer's statistics
    std::ostringstream value(std::ios_base::binary);
    it->second->write(value);
    PutString(h, it->first);
    PutString(h, it->second->typeName());
    PutString(h, value.str());
  }
}

void PutTransform(Sha256& h, const openvdb::GridBase& grid) {
  const openvdb::math::Mat4d m = grid.transform().baseMap()->getAffineMap()->getMat4();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) PutValue(h, m(r, c));
}

// Active values (voxels and tiles), then inactive ones off the background.
template <typename GridT>
void PutTree(Sha256& h, const GridT& grid) {
  using ValueT = typename GridT::ValueType;
  const ValueT background = grid.background();
  PutValue(h, background);
  auto put = [&](const auto& it) {
    const openvdb::CoordBBox box = it.getBoundingBox();
    const openvdb::Coord lo = box.min(), dim = box.dim();
    const int32_t at[6] = {lo.x(), lo.y(), lo.z(), dim.x(), dim.y(), dim.z()};
    Put(h, at, sizeof at);
    const ValueT v = it.getValue();
    PutValue(h, v);
  };
  uint64_t active = 0;
  for (auto it = grid.cbeginValueOn(); it; ++it, ++active) put(it);
  PutValue(h, active);
  uint64_t off = 0;
  for (auto it = grid.cbeginValueOff(); it; ++it)
    if (!openvdb::math::isExactlyEqual(it.getValue(), background)) put(it), ++off;
  PutValue(h, off);
}

using Types = openvdb::TypeList<openvdb::FloatGrid, openvdb::DoubleGrid, openvdb::Vec3SGrid,
                                openvdb::Int32Grid, openvdb::Int64Grid, openvdb::BoolGrid,
                                openvdb::MaskGrid>;

absl::Status PutGrid(Sha256& h, const openvdb::GridBase& grid) {
  PutString(h, grid.getName());
  PutString(h, grid.valueType());
  PutString(h, openvdb::GridBase::gridClassToString(grid.getGridClass()));
  PutString(h, openvdb::GridBase::vecTypeToString(grid.getVectorType()));
  PutTransform(h, grid);
  PutMetadata(h, grid);
  const bool known = grid.apply<Types>([&](const auto& g) { PutTree(h, g); });
  if (!known) return absl::UnimplementedError(absl::StrCat("grid type ", grid.type()));
  return absl::OkStatus();
}

struct PngReadGuard {
  png_structp png = nullptr;
  png_infop info = nullptr;
  ~PngReadGuard() { png_destroy_read_struct(&png, info ? &info : nullptr, nullptr); }
};

// libpng reports errors by longjmp: nothing with a destructor lives between
// the setjmp and the calls that may jump.
bool ReadRows(PngReadGuard& g, FILE* f) {
  if (setjmp(png_jmpbuf(g.png))) return false;
  png_init_io(g.png, f);
  png_read_png(g.png, g.info, PNG_TRANSFORM_IDENTITY, nullptr);
  return true;
}

}  // namespace

absl::StatusOr<std::string> VdbContentDigest(const std::filesystem::path& path) {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
  openvdb::GridPtrVecPtr grids;
  try {
    openvdb::io::File file(path.string());
    file.open(/*delayLoad=*/false);
    grids = file.getGrids();
    file.close();
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("reading ", path.string(), ": ", e.what()));
  }
  std::vector<openvdb::GridBase::ConstPtr> sorted(grids->begin(), grids->end());
  std::stable_sort(sorted.begin(), sorted.end(), [](const auto& a, const auto& b) {
    return a->getName() < b->getName();
  });
  Sha256 h;
  PutString(h, "vdb");
  for (const auto& grid : sorted)
    if (absl::Status st = PutGrid(h, *grid); !st.ok()) return st;
  return h.HexDigest();
}

absl::StatusOr<std::string> PngContentDigest(const std::filesystem::path& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return absl::NotFoundError(absl::StrCat("cannot open ", path.string()));
  PngReadGuard g;
  g.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  if (g.png) g.info = png_create_info_struct(g.png);
  if (!g.info || !ReadRows(g, f.get()))
    return absl::InvalidArgumentError(absl::StrCat("libpng cannot read ", path.string()));
  const uint32_t shape[4] = {png_get_image_width(g.png, g.info),
                             png_get_image_height(g.png, g.info),
                             png_get_bit_depth(g.png, g.info), png_get_channels(g.png, g.info)};
  Sha256 h;
  PutString(h, "png");
  Put(h, shape, sizeof shape);
  const size_t row_bytes = png_get_rowbytes(g.png, g.info);
  png_bytepp rows = png_get_rows(g.png, g.info);
  for (uint32_t r = 0; r < shape[1]; ++r) Put(h, rows[r], row_bytes);
  return h.HexDigest();
}

absl::StatusOr<std::string> ContentDigest(const std::filesystem::path& path) {
  char head[8] = {};
  {
    std::ifstream in(path, std::ios::binary);
    if (!in) return absl::NotFoundError(absl::StrCat("cannot open ", path.string()));
    in.read(head, sizeof head);
  }
  static constexpr unsigned char kPng[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  const int64_t vdb_magic = 0x56444220;  // OpenVDB's, little-endian
  if (std::memcmp(head, kPng, 8) == 0) return PngContentDigest(path);
  if (std::memcmp(head, &vdb_magic, 8) == 0) return VdbContentDigest(path);
  auto sha = Sha256File(path);
  if (!sha.ok()) return sha.status();
  return "bytes:" + *sha;
}

}  // namespace nimbus::testing
