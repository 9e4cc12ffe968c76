// Early-return helpers for absl::Status and absl::StatusOr<T>.
//
// NIMBUS_RETURN_IF_ERROR(expr) evaluates `expr` (an absl::Status or an
// absl::StatusOr<T>) once and, if it is not OK, returns its status from the
// enclosing function, which may return absl::Status or any absl::StatusOr.
//
// NIMBUS_ASSIGN_OR_RETURN(lhs, expr) evaluates `expr` (an absl::StatusOr<T>)
// once; on error it returns the status, otherwise it moves the value into
// `lhs`, which is a new declaration (`auto x`, `const Foo& y`, `Foo z`) or an
// existing variable. A reference binds to the value kept in a hidden local,
// so it stays valid until the end of the enclosing scope.
//
// Example:
//
//   absl::StatusOr<Mesh> LoadAndCheck(const std::string& path) {
//     NIMBUS_ASSIGN_OR_RETURN(Mesh mesh, ReadMesh(path));
//     NIMBUS_RETURN_IF_ERROR(CheckClosed(mesh));
//     return mesh;
//   }
//
// The status is returned unchanged: same code, same message.
//
// NIMBUS_ASSIGN_OR_RETURN expands to several statements, so it cannot be the
// body of an unbraced if/for, and its hidden local is named after the line:
// use it at most once per source line. `lhs` must not contain a top-level
// comma (name the type with an alias); `expr` may.
#pragma once

#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace nimbus::status_macros_internal {

inline absl::Status AsStatus(absl::Status s) { return s; }

template <typename T>
absl::Status AsStatus(const absl::StatusOr<T>& s) {
  return s.status();
}

}  // namespace nimbus::status_macros_internal

#define NIMBUS_STATUS_MACROS_CONCAT_INNER_(a, b) a##b
#define NIMBUS_STATUS_MACROS_CONCAT_(a, b) NIMBUS_STATUS_MACROS_CONCAT_INNER_(a, b)

#define NIMBUS_RETURN_IF_ERROR(...)                                  \
  do {                                                               \
    if (::absl::Status nimbus_macro_status_ =                        \
            ::nimbus::status_macros_internal::AsStatus(__VA_ARGS__); \
        !nimbus_macro_status_.ok())                                  \
      return nimbus_macro_status_;                                   \
  } while (false)

#define NIMBUS_ASSIGN_OR_RETURN(lhs, ...)                                                       \
  NIMBUS_ASSIGN_OR_RETURN_IMPL_(NIMBUS_STATUS_MACROS_CONCAT_(nimbus_macro_statusor_, __LINE__), \
                                lhs, __VA_ARGS__)

#define NIMBUS_ASSIGN_OR_RETURN_IMPL_(statusor, lhs, ...)  \
  auto statusor = (__VA_ARGS__);                           \
  if (!statusor.ok()) return std::move(statusor).status(); \
  lhs = *std::move(statusor)
