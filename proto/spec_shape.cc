#include "proto/spec_shape.h"

#include <algorithm>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "google/protobuf/descriptor.h"
#include "google/protobuf/message.h"
#include "google/protobuf/unknown_field_set.h"

namespace nimbus::spec {

namespace {

using google::protobuf::FieldDescriptor;
using google::protobuf::Message;
using google::protobuf::Reflection;

// Messages nest at most 100 levels on the wire (protobuf's own limit), so
// the walk's recursion is bounded.
class ShapeWalk {
 public:
  explicit ShapeWalk(const Limits& limits) : limits_(limits) {}

  absl::Status Walk(const Message& m, const std::string& path) {
    const Reflection* r = m.GetReflection();
    const auto& unknown = r->GetUnknownFields(m);
    if (!unknown.empty())
      return Refuse(path.empty() ? "spec" : path,
                    absl::StrCat("has a field this server does not know (field number ",
                                 unknown.field(0).number(),
                                 "); use a client of this server's version or remove it"));
    std::vector<const FieldDescriptor*> fields;
    r->ListFields(m, &fields);
    for (const FieldDescriptor* f : fields)
      if (absl::Status st = WalkField(m, *r, *f, Join(path, f->name())); !st.ok()) return st;
    return absl::OkStatus();
  }

 private:
  static std::string Join(const std::string& path, const std::string& name) {
    return path.empty() ? name : absl::StrCat(path, ".", name);
  }

  static absl::Status Refuse(const std::string& path, const std::string& what) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": ", what));
  }

  int Bound(const FieldDescriptor& f) const {
    if (f.name() == "stops" && f.containing_type()->name() == "Palette") return kMaxPaletteStops;
    if (f.name() == "maps") return std::max(kMaxRepeatedEntries, limits_.max_maps);
    return kMaxRepeatedEntries;
  }

  absl::Status WalkField(const Message& m, const Reflection& r, const FieldDescriptor& f,
                         const std::string& path) {
    if (!f.is_repeated()) {
      if (f.cpp_type() != FieldDescriptor::CPPTYPE_MESSAGE) return absl::OkStatus();
      return Walk(r.GetMessage(m, &f), path);
    }
    const int n = r.FieldSize(m, &f);
    if (n > Bound(f))
      return Refuse(path, absl::StrCat("must have at most ", Bound(f), " entries, got ", n));
    if (f.cpp_type() != FieldDescriptor::CPPTYPE_MESSAGE) return absl::OkStatus();
    for (int i = 0; i < n; ++i)
      if (absl::Status st = Walk(r.GetRepeatedMessage(m, &f, i), absl::StrCat(path, "[", i, "]"));
          !st.ok())
        return st;
    return absl::OkStatus();
  }

  const Limits& limits_;
};

}  // namespace

absl::Status CheckSpecShape(const v1::JobSpec& spec, const Limits& limits) {
  if (const size_t bytes = spec.ByteSizeLong(); bytes > kMaxSpecBytes)
    return absl::InvalidArgumentError(
        absl::StrCat("spec: must be at most ", kMaxSpecBytes, " bytes serialised, got ", bytes));
  return ShapeWalk(limits).Walk(spec, "");
}

}  // namespace nimbus::spec
