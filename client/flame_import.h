// @brief Converts a flame genome in flam3's XML format (flam3, Apophysis,
// JWildfire) into a Nimbus spec, so that artists' existing genomes render in
// Nimbus as they do in flam3-render.
//
//   absl::StatusOr<FlameImport> got = ImportFlame(xml_text, {});
//   if (!got.ok()) return got.status();       // names the genome, xform, attribute
//   for (const std::string& w : got->warnings) std::cerr << w << "\n";
//   std::cout << spec::SpecToJson(got->spec);
//
// What maps to what is documented in docs/flame_import.md.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "nimbus/v1/spec.pb.h"

namespace nimbus::client {

struct FlameImportOptions {
  /// Which genome of a file holding several: its name, or its index from 0.
  /// Empty: the only one (a file with several must choose).
  std::string genome;
  /// Plotted samples; 0 takes flam3's quality x width x height.
  uint64_t iterations = 0;
  uint64_t seed = 1;
  /// Make a picture the size of flam3's (a PNG, log density, looking down
  /// z) instead of a one-voxel-thick volume.
  bool picture = false;
};

struct FlameImport {
  v1::JobSpec spec;
  /// What could not be carried over exactly, one sentence each.
  std::vector<std::string> warnings;
  /// Names of every genome in the file, in file order (unnamed: "#index").
  std::vector<std::string> genome_names;
};

/// Parses the XML and converts the chosen genome. INVALID_ARGUMENT names the
/// line, element and attribute of what cannot be read or has no Nimbus
/// equivalent (an unsupported variation, a malformed coefficient list).
absl::StatusOr<FlameImport> ImportFlame(std::string_view xml, const FlameImportOptions& options);

}  // namespace nimbus::client
