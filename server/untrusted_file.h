// Parsing untrusted files where they cannot hurt the server.
//
// OpenVDB 10's reader is not hardened: a truncated or bit-flipped .vdb can
// make it allocate many gigabytes or throw a message of a gigabyte. Mesh
// parsers are ours, but an upload is still hostile input. So every asset
// is first read whole by a short-lived child process with limits on its
// address space and CPU time (and a wall-clock deadline enforced by the
// parent); a poison file costs that child, never nimbusd. A grid that
// reads cleanly is re-written there by Nimbus's writer, and nimbusd reads
// only that copy: undefined behaviour in OpenVDB's reader need not show in
// the child as well as in nimbusd.
//
// How the child starts: the parent posix_spawn()s /proc/self/exe (safe in
// a multithreaded process: nothing of ours runs between fork and exec) as
// "nimbus-file-check" with NIMBUS_FILE_CHECK in its environment. A
// constructor in untrusted_file.cc sees both before main, applies the
// limits to itself, runs the check and _exits, so every binary linking the server library (nimbusd
// and the tests) is its own checker and no extra executable is installed.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

#include "absl/status/status.h"
#include "nimbus/v1/spec.pb.h"

namespace nimbus::server {

enum class UntrustedKind { kVdbGrid, kMesh };

struct UntrustedFile {
  UntrustedKind kind = UntrustedKind::kVdbGrid;
  std::filesystem::path path;
  /// Meshes: ".obj", ".ply", ".stl" when known (content-addressed files have
  /// no extension); empty lets the loader tell by content.
  std::string format;
  /// Grids: a grid the file must hold as a float grid; empty: any file of
  /// readable grids that holds at least one float grid.
  std::string grid_name;
  /// Grids: where the checker writes the float grids it read, re-serialised
  /// by Nimbus (empty: nowhere). nimbusd reads only that copy.
  std::filesystem::path laundered;
};

struct SandboxLimits {
  /// RLIMIT_AS of the checker.
  uint64_t memory_bytes = uint64_t{2} << 30;
  /// RLIMIT_CPU of the checker.
  int cpu_seconds = 60;
  /// The parent kills the checker after this long (a blocked reader uses
  /// no CPU).
  int wall_seconds = 120;
};

/// Reads `file` whole in a sandboxed child. OK when it parses;
/// INVALID_ARGUMENT with a short reason ("not a readable VDB file: ...",
/// "not a readable mesh: ...") when it does not, or when the reader ran out
/// of memory, CPU or time; UNAVAILABLE when no checker could be started.
/// Messages never hold more than a few hundred bytes of the reader's text.
absl::Status CheckUntrustedFile(const UntrustedFile& file, const SandboxLimits& limits = {});

/// CheckUntrustedFile for a content-addressed asset, remembered per
/// (sha256, kind, grid name) for the life of the process: an asset is
/// checked once at upload or first use, then never again.
absl::Status CheckStoredAsset(const std::string& sha256, const UntrustedFile& file,
                              const SandboxLimits& limits = {});

/// Checks every mesh and grid asset of `spec` (uploaded by sha256 under
/// `asset_dir`, or a local path) before anything in this process parses
/// it. INVALID_ARGUMENT names the field:
///   "set_ifs.start.grid.asset: grid asset cow.vdb (sha256 3fa2c81d9e07...):
///    not a readable VDB file: <short reason>".
/// Assets that cannot be found are left to the converter's own errors.
/// Without `allow_local_paths` (a server reached over the network) an asset
/// named by path is refused with spec::LocalPathRefused before any file
/// system call.
absl::Status CheckSpecAssets(const v1::JobSpec& spec, const std::filesystem::path& asset_dir,
                             bool allow_local_paths, const SandboxLimits& limits = {});

}  // namespace nimbus::server
