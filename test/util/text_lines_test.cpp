#include "rotation_averaging/util/text_lines.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string_view>
#include <vector>

namespace rotation_averaging {
namespace {

TEST(TextLines, QuaternionsAreFourNumbersOfUnitNorm) {
  double q[4];
  const std::vector<std::string_view> unit = {"0.5", "0.5", "-0.5", "0.5"};
  ASSERT_TRUE(ParseQuaternion(unit.data(), q));
  EXPECT_EQ(q[2], -0.5);
  EXPECT_TRUE(IsUnitQuaternion(q));
  const std::vector<std::string_view> long_one = {"1", "0", "0", "0.01"};
  ASSERT_TRUE(ParseQuaternion(long_one.data(), q));
  EXPECT_FALSE(IsUnitQuaternion(q));
  const std::vector<std::string_view> not_a_number = {"1", "0", "x", "0"};
  EXPECT_FALSE(ParseQuaternion(not_a_number.data(), q));
  const std::vector<std::string_view> nan = {"nan", "0", "0", "0"};
  ASSERT_TRUE(ParseQuaternion(nan.data(), q));  // a number to the parser
  EXPECT_FALSE(IsUnitQuaternion(q));
}

}  // namespace
}  // namespace rotation_averaging
