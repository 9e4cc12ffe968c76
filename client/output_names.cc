#include "client/output_names.h"

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "proto/result_files.h"

namespace nimbus::client {

namespace {

std::string FormatName(const std::string& extension) {
  if (extension == ".vdb") return "an OpenVDB volume";
  if (extension == ".exr") return "an OpenEXR picture";
  return "a PNG picture";
}

}  // namespace

absl::StatusOr<std::filesystem::path> MainOutputPath(const std::filesystem::path& out,
                                                     const v1::JobSpec& spec) {
  const std::string given = absl::AsciiStrToLower(out.extension().string());
  const std::string main = spec::MainResultExtension(spec);
  if (given.empty() || given == main) return out;
  const std::string picture = spec::SidePictureExtension(spec);
  if (given == picture) return std::filesystem::path(out).replace_extension(main);
  std::filesystem::path suggested = std::filesystem::path(out).replace_extension(main);
  std::string hint = absl::StrCat("; name it ", suggested.string());
  if (!picture.empty())
    absl::StrAppend(&hint, " (its picture is written beside it as ",
                    std::filesystem::path(out).replace_extension(picture).string(), ")");
  return absl::InvalidArgumentError(absl::StrCat("-o ", out.string(),
                                                 ": this job's main result is ", FormatName(main),
                                                 ", not a ", given, " file", hint));
}

absl::Status CheckOutputExtension(const std::filesystem::path& out, const std::string& file_name) {
  const std::string given = absl::AsciiStrToLower(out.extension().string());
  const std::string actual =
      absl::AsciiStrToLower(std::filesystem::path(file_name).extension().string());
  if (given.empty() || actual.empty() || given == actual) return absl::OkStatus();
  return absl::InvalidArgumentError(
      absl::StrCat("-o ", out.string(), ": the file is ", file_name, "; name it ",
                   std::filesystem::path(out).replace_extension(actual).string()));
}

}  // namespace nimbus::client
