// Guards the -fno-tree-slp-vectorize workaround in CMakeLists.txt: without it g++ 12.2
// at -O2 leaves the first two of three double->float->double casts unrounded.
#include <gtest/gtest.h>

#include <array>

#include "util/geometry.hpp"

namespace {

[[gnu::noinline]] qemflow::Point round_to_float(const qemflow::Point& p) {
  return {static_cast<float>(p[0]), static_cast<float>(p[1]), static_cast<float>(p[2])};
}

}  // namespace

TEST(FloatRounding, EveryComponentIsRounded) {
  const qemflow::Point q = round_to_float({0.1, 0.2, 0.3});
  EXPECT_EQ(q[0], static_cast<double>(0.1f));
  EXPECT_EQ(q[1], static_cast<double>(0.2f));
  EXPECT_EQ(q[2], static_cast<double>(0.3f));
}
