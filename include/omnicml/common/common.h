// Errors, invariant checks and small numeric helpers shared by every module.
//
// Library code never calls exit(): expected failures (a bad file, a bad image, a bad
// configuration) throw omnicml::Error with a message that says what is wrong and where
// (file, line, field). Broken invariants throw omnicml::InternalError via OMNICML_CHECK.
// Applications map Error to exit code 2 and InternalError to exit code 1.
#ifndef OMNICML_COMMON_COMMON_H_
#define OMNICML_COMMON_COMMON_H_

#include <numbers>
#include <sstream>
#include <stdexcept>
#include <string>

namespace omnicml {

// An expected failure caused by the input: bad file, bad image, bad option value.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A broken invariant inside the library (a bug, not bad input).
class InternalError : public std::logic_error {
 public:
  using std::logic_error::logic_error;
};

namespace internal {
[[noreturn]] void FailCheck(const char* file, int line, const char* expr, const std::string& msg);
}  // namespace internal

// Formats its arguments with operator<< into one string: StrCat("line ", 3, ": bad").
template <typename... Args>
std::string StrCat(const Args&... args) {
  std::ostringstream os;
  (os << ... << args);
  return os.str();
}

constexpr double kPi = std::numbers::pi;
constexpr double kTwoPi = 2.0 * std::numbers::pi;

// Wraps an angle in radians to (-pi, pi].
double WrapAngle(double angle_rad);

}  // namespace omnicml

// Checks an invariant; on failure throws omnicml::InternalError naming file and line.
// Usage: OMNICML_CHECK(n > 0) << "n=" << n;   (the streamed text is optional)
#define OMNICML_CHECK(condition) \
  if (condition) {               \
  } else                         \
    ::omnicml::internal::CheckFailer(__FILE__, __LINE__, #condition).stream()

namespace omnicml::internal {
// Collects the streamed message and throws when destroyed (end of the full expression).
class CheckFailer {
 public:
  CheckFailer(const char* file, int line, const char* expr)
      : file_(file), line_(line), expr_(expr) {}
  CheckFailer(const CheckFailer&) = delete;
  CheckFailer& operator=(const CheckFailer&) = delete;
  ~CheckFailer() noexcept(false) { FailCheck(file_, line_, expr_, os_.str()); }
  std::ostream& stream() { return os_; }

 private:
  const char* file_;
  int line_;
  const char* expr_;
  std::ostringstream os_;
};
}  // namespace omnicml::internal

#endif  // OMNICML_COMMON_COMMON_H_
