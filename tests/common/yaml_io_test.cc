#include "omnicml/common/yaml_io.h"

#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/common/limits.h"

namespace omnicml {
namespace {
using ::testing::HasSubstr;

std::string ErrorOf(const std::string& text) {
  try {
    LoadYaml(text, "f.yaml");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// The "billion laughs": ten levels of ten aliases each (10^10 nodes expanded) is refused
// after at most kMaxYamlNodes steps, under an unknown key as anywhere else.
TEST(LoadYaml, AliasBombRefused) {
  std::string text = "a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]\n";
  for (int i = 1; i < 10; ++i) {
    text += StrCat("a", i, ": &a", i, " [");
    for (int k = 0; k < 10; ++k) text += StrCat(k ? ", " : "", "*a", i - 1);
    text += "]\n";
  }
  text += "unknown_key: *a9\n";
  const std::string message = ErrorOf(text);
  EXPECT_THAT(message, HasSubstr("f.yaml:"));
  EXPECT_THAT(message, HasSubstr(StrCat("more than ", kMaxYamlNodes, " nodes")));
  // A few aliases are fine.
  EXPECT_EQ(ErrorOf("a: &x {k: 1}\nb: *x\nc: *x\n"), "");
}

// Duplicate keys are refused at any depth, naming the key's line.
TEST(LoadYaml, DuplicateKeysRefused) {
  EXPECT_EQ(ErrorOf("a: 1\nb: 2\n"), "");
  EXPECT_THAT(ErrorOf("a: 1\nb: 2\na: 3\n"), HasSubstr("f.yaml:3: duplicate key 'a'"));
  EXPECT_THAT(ErrorOf("top:\n  x: 1\n  x: 2\n"), HasSubstr("f.yaml:3: duplicate key 'x'"));
  EXPECT_THAT(ErrorOf("- {p: 1, p: 2}\n"), HasSubstr("duplicate key 'p'"));
}

// Text that is not UTF-8 is refused naming the line, without echoing the bytes.
TEST(LoadYaml, NonUtf8Refused) {
  const std::string bad = "a: 1\nb: caf\xe9\n";
  const std::string message = ErrorOf(bad);
  EXPECT_THAT(message, HasSubstr("f.yaml:2: not valid UTF-8"));
  EXPECT_EQ(message.find('\xe9'), std::string::npos);
  EXPECT_EQ(ErrorOf("name: \"caf\xc3\xa9 \xe2\x82\xac\"\n"), "");  // café €
  EXPECT_EQ(FirstNonUtf8Line("\xc0\x80"), 1u);                     // overlong NUL
  EXPECT_EQ(FirstNonUtf8Line("x\n\xed\xa0\x80"), 2u);              // a UTF-16 surrogate
  EXPECT_EQ(FirstNonUtf8Line("\xf4\x90\x80\x80"), 1u);             // above U+10FFFF
  EXPECT_EQ(FirstNonUtf8Line("\xf0\x9f\x98\x80"), 0u);             // an emoji
}

// Nesting deeper than kMaxYamlDepth is refused; syntax errors name the line.
TEST(LoadYaml, DepthAndSyntax) {
  std::string deep;
  for (int i = 0; i <= kMaxYamlDepth + 1; ++i) deep += "[";
  for (int i = 0; i <= kMaxYamlDepth + 1; ++i) deep += "]";
  EXPECT_THAT(ErrorOf(deep), HasSubstr("deeper than"));
  EXPECT_THAT(ErrorOf("a: [1, 2\n"), HasSubstr("f.yaml:"));
}

}  // namespace
}  // namespace omnicml
