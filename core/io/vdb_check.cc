// The OpenVDB side of CheckUntrustedVdb (vdb_io.h), run by the sandboxed
// file checker of server/untrusted_file.cc.
#include <openvdb/openvdb.h>

#include <cstdio>
#include <cstring>
#include <new>
#include <string>

#include "absl/strings/str_cat.h"
#include "core/io/vdb_impl.h"
#include "core/io/vdb_internal.h"

namespace nimbus::vdb_impl {

namespace {

// Re-writes the float grids with OpenVDB's writer: nimbusd then reads only
// bytes made from grids in memory, never the uploaded ones.
absl::Status WriteLaundered(const openvdb::GridPtrVec& grids,
                            const std::filesystem::path& out) {
  openvdb::GridPtrVec floats;
  for (const openvdb::GridBase::Ptr& g : grids)
    if (g && g->isType<openvdb::FloatGrid>()) floats.push_back(g);
  if (floats.empty()) return absl::InvalidArgumentError("the file holds no float grid");
  const std::string tmp = absl::StrCat(out.string(), ".tmp");
  openvdb::io::File file(tmp);
  file.write(floats);
  file.close();
  if (std::rename(tmp.c_str(), out.c_str()) != 0)
    return absl::InvalidArgumentError("cannot store the checked grids");
  return absl::OkStatus();
}

absl::Status Check(const std::filesystem::path& path, const std::filesystem::path& laundered) {
  vdb_internal::InitOpenVdb();
  openvdb::io::File file(path.string());
  // No delayed loading: every buffer is read here, not later by a job.
  file.open(/*delayLoad=*/false);
  openvdb::GridPtrVecPtr grids = file.getGrids();
  file.close();
  if (!grids || grids->empty()) return absl::InvalidArgumentError("the file holds no grids");
  // Walk every tree once, so nothing of it stays unread.
  for (const openvdb::GridBase::Ptr& g : *grids)
    if (g) (void)g->activeVoxelCount();
  return laundered.empty() ? absl::OkStatus() : WriteLaundered(*grids, laundered);
}

}  // namespace

absl::Status CheckUntrustedVdb(const std::filesystem::path& path,
                               const std::filesystem::path& laundered) {
  try {
    return Check(path, laundered);
  } catch (const std::bad_alloc&) {
    return absl::InvalidArgumentError("the reader ran out of memory");
  } catch (const std::exception& e) {
    // The reader's text can be a gigabyte: keep its start, unmeasured.
    return absl::InvalidArgumentError(std::string(e.what(), ::strnlen(e.what(), 300)));
  } catch (...) {
    return absl::InvalidArgumentError("the reader failed");
  }
}

}  // namespace nimbus::vdb_impl
