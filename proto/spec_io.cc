#include "proto/spec_io.h"

#include <google/protobuf/io/tokenizer.h>
#include <google/protobuf/text_format.h>
#include <google/protobuf/util/json_util.h>

#include <fstream>
#include <sstream>

#include "absl/strings/str_cat.h"

namespace nimbus::spec {

namespace {

// The same depth protobuf's binary decoder allows, so any spec read here can
// also be sent to a server.
constexpr int kMaxTextNesting = 100;

// Collects text-format parser errors with their positions.
class ErrorCollector : public google::protobuf::io::ErrorCollector {
 public:
  explicit ErrorCollector(std::string source) : source_(std::move(source)) {}
  void AddError(int line, google::protobuf::io::ColumnNumber column,
                const std::string& message) override {
    if (first_.empty())
      first_ = absl::StrCat(source_, ":", line + 1, ":", column + 1, ": ", message);
  }
  const std::string& first() const { return first_; }

 private:
  std::string source_;
  std::string first_;
};

}  // namespace

absl::StatusOr<v1::JobSpec> ParseSpec(const std::string& text, SpecFormat format,
                                      const std::string& source_name) {
  if (format == SpecFormat::kAuto) {
    const size_t p = text.find_first_not_of(" \t\r\n");
    format = (p != std::string::npos && text[p] == '{') ? SpecFormat::kJson : SpecFormat::kText;
  }
  v1::JobSpec spec;
  if (format == SpecFormat::kJson) {
    google::protobuf::util::JsonParseOptions options;
    options.ignore_unknown_fields = false;
    const auto st = google::protobuf::util::JsonStringToMessage(text, &spec, options);
    if (!st.ok())
      return absl::InvalidArgumentError(
          absl::StrCat(source_name, ": malformed JSON spec: ", std::string(st.message())));
    return spec;
  }
  google::protobuf::TextFormat::Parser parser;
  ErrorCollector errors(source_name);
  parser.RecordErrorsTo(&errors);
  // The parser recurses once per nested message; without a bound a deep
  // spec exhausts the stack.
  parser.SetRecursionLimit(kMaxTextNesting);
  if (!parser.ParseFromString(text, &spec))
    return absl::InvalidArgumentError(
        errors.first().empty() ? absl::StrCat(source_name, ": malformed text-format spec")
                               : absl::StrCat("malformed text-format spec: ", errors.first()));
  return spec;
}

absl::StatusOr<v1::JobSpec> LoadSpecFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open spec file ", path.string()));
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string ext = path.extension().string();
  SpecFormat format = SpecFormat::kAuto;
  if (ext == ".json") format = SpecFormat::kJson;
  if (ext == ".txtpb" || ext == ".textproto" || ext == ".pbtxt") format = SpecFormat::kText;
  return ParseSpec(ss.str(), format, path.string());
}

std::string SpecToJson(const v1::JobSpec& spec) {
  std::string out;
  google::protobuf::util::JsonPrintOptions options;
  options.add_whitespace = true;
  options.preserve_proto_field_names = true;
  (void)google::protobuf::util::MessageToJsonString(spec, &out, options);
  return out;
}

}  // namespace nimbus::spec
