// Reading and writing spec files with protobuf's own JSON and text-format
// parsers.
#pragma once

#include <filesystem>
#include <string>

#include "absl/status/statusor.h"
#include "nimbus/v1/spec.pb.h"

namespace nimbus::spec {

enum class SpecFormat { kAuto, kJson, kText };

/// Parses spec text. kAuto picks JSON when the first non-blank character is
/// '{', text format otherwise. Errors carry line and column.
absl::StatusOr<v1::JobSpec> ParseSpec(const std::string& text, SpecFormat format,
                                      const std::string& source_name = "spec");

/// Reads and parses a spec file; .json means JSON, .txtpb/.textproto/.pbtxt
/// text format, anything else is sniffed.
absl::StatusOr<v1::JobSpec> LoadSpecFile(const std::filesystem::path& path);

/// The spec as indented JSON (proto field names).
std::string SpecToJson(const v1::JobSpec& spec);

}  // namespace nimbus::spec
