#include "core/base/status_macros.h"

#include <gtest/gtest.h>

#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace nimbus {
namespace {

// Each helper counts its calls, so the tests can see an expression is
// evaluated exactly once.
struct Calls {
  int n = 0;
};

absl::Status StatusOf(Calls& calls, absl::Status s) {
  ++calls.n;
  return s;
}

absl::StatusOr<int> IntOf(Calls& calls, absl::StatusOr<int> v) {
  ++calls.n;
  return v;
}

absl::Status ReturnIfError(Calls& calls, absl::Status s, bool* reached_end) {
  NIMBUS_RETURN_IF_ERROR(StatusOf(calls, s));
  *reached_end = true;
  return absl::OkStatus();
}

TEST(ReturnIfError, PassesOkAndReturnsTheErrorUnchanged) {
  Calls calls;
  bool end = false;
  EXPECT_TRUE(ReturnIfError(calls, absl::OkStatus(), &end).ok());
  EXPECT_TRUE(end);
  EXPECT_EQ(calls.n, 1);

  end = false;
  const absl::Status got = ReturnIfError(calls, absl::NotFoundError("no map 'x'"), &end);
  EXPECT_FALSE(end);
  EXPECT_EQ(calls.n, 2);
  EXPECT_EQ(got, absl::NotFoundError("no map 'x'"));
}

// A StatusOr return type and a StatusOr argument.
absl::StatusOr<std::string> Describe(Calls& calls, absl::StatusOr<int> v) {
  NIMBUS_RETURN_IF_ERROR(IntOf(calls, v));
  return std::string("fine");
}

TEST(ReturnIfError, WorksInStatusOrFunctionsAndOnStatusOr) {
  Calls calls;
  EXPECT_EQ(*Describe(calls, 3), "fine");
  const auto bad = Describe(calls, absl::OutOfRangeError("index 9 of 4"));
  EXPECT_EQ(bad.status(), absl::OutOfRangeError("index 9 of 4"));
  EXPECT_EQ(calls.n, 2);
}

TEST(ReturnIfError, IsOneStatementInAnUnbracedIf) {
  auto f = [](bool check, absl::Status s) -> absl::Status {
    if (check)
      NIMBUS_RETURN_IF_ERROR(s);
    else
      return absl::CancelledError("not checked");
    return absl::OkStatus();
  };
  EXPECT_EQ(f(true, absl::InternalError("x")), absl::InternalError("x"));
  EXPECT_TRUE(f(true, absl::OkStatus()).ok());
  EXPECT_EQ(f(false, absl::OkStatus()).code(), absl::StatusCode::kCancelled);
}

absl::StatusOr<int> Sum(Calls& calls, absl::StatusOr<int> a, absl::StatusOr<int> b) {
  NIMBUS_ASSIGN_OR_RETURN(const int x, IntOf(calls, a));
  NIMBUS_ASSIGN_OR_RETURN(auto y, IntOf(calls, b));
  return x + y;
}

TEST(AssignOrReturn, DeclaresAndReturnsTheFirstError) {
  Calls calls;
  EXPECT_EQ(*Sum(calls, 2, 40), 42);
  EXPECT_EQ(calls.n, 2);
  EXPECT_EQ(Sum(calls, absl::InvalidArgumentError("a: bad"), 1).status(),
            absl::InvalidArgumentError("a: bad"));
  EXPECT_EQ(calls.n, 3);  // b was never evaluated
  EXPECT_EQ(Sum(calls, 1, absl::InvalidArgumentError("b: bad")).status(),
            absl::InvalidArgumentError("b: bad"));
  EXPECT_EQ(calls.n, 5);
}

absl::Status Store(absl::StatusOr<int> v, int* out) {
  int existing = -1;
  NIMBUS_ASSIGN_OR_RETURN(existing, std::move(v));
  *out = existing;
  return absl::OkStatus();
}

TEST(AssignOrReturn, AssignsAnExistingVariableInAStatusFunction) {
  int out = 0;
  EXPECT_TRUE(Store(7, &out).ok());
  EXPECT_EQ(out, 7);
  EXPECT_EQ(Store(absl::DataLossError("torn"), &out), absl::DataLossError("torn"));
  EXPECT_EQ(out, 7);
}

absl::StatusOr<std::unique_ptr<int>> Boxed(int v) { return std::make_unique<int>(v); }

absl::StatusOr<int> Unbox() {
  // Move-only values are moved out, not copied.
  NIMBUS_ASSIGN_OR_RETURN(std::unique_ptr<int> p, Boxed(5));
  return *p;
}

TEST(AssignOrReturn, MovesMoveOnlyValues) { EXPECT_EQ(*Unbox(), 5); }

absl::StatusOr<std::vector<int>> Numbers() { return std::vector<int>{1, 2, 3}; }

absl::StatusOr<size_t> ReferenceStaysValid() {
  NIMBUS_ASSIGN_OR_RETURN(const std::vector<int>& v, Numbers());
  // Later statements still see the value the reference is bound to.
  NIMBUS_ASSIGN_OR_RETURN(const std::vector<int>& w, Numbers());
  return v.size() + w.size() + size_t(v[2]);
}

TEST(AssignOrReturn, ConstReferenceBindsToAValueThatLivesOn) {
  EXPECT_EQ(*ReferenceStaysValid(), 9u);
}

absl::StatusOr<int> CommaInExpression() {
  // The expression may contain commas outside parentheses.
  NIMBUS_ASSIGN_OR_RETURN(auto m, absl::StatusOr<std::map<int, int>>(std::map<int, int>{{1, 2}}));
  return m.at(1);
}

TEST(AssignOrReturn, ExpressionMayContainCommas) { EXPECT_EQ(*CommaInExpression(), 2); }

}  // namespace
}  // namespace nimbus
