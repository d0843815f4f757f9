// Guards the -fno-tree-slp-vectorize workaround in CMakeLists.txt: without it g++ 12.2
// at -O2 leaves the first two of three double->float->double casts unrounded.
#include <gtest/gtest.h>

#include <array>

#include "util/geometry.hpp"

// External linkage and volatile inputs keep the compiler from specialising the call
// away, which would hide the miscompile.
[[gnu::noinline]] qemflow::Point qemflow_test_round_to_float(const qemflow::Point& p) {
  return {static_cast<float>(p[0]), static_cast<float>(p[1]), static_cast<float>(p[2])};
}

TEST(FloatRounding, EveryComponentIsRounded) {
  volatile double x = 0.1, y = 0.2, z = 0.3;
  const qemflow::Point q = qemflow_test_round_to_float({x, y, z});
  EXPECT_EQ(q[0], static_cast<double>(0.1f));
  EXPECT_EQ(q[1], static_cast<double>(0.2f));
  EXPECT_EQ(q[2], static_cast<double>(0.3f));
}
