#include "config/size.hpp"

#include <gtest/gtest.h>

#include "util/error.hpp"

using qemflow::config::format_size;
using qemflow::config::parse_size;

TEST(ParseSize, AcceptsUnitsAsUsersWriteThem) {
  EXPECT_EQ(parse_size("65536"), 65536u);
  EXPECT_EQ(parse_size("4G"), 4ull << 30);
  EXPECT_EQ(parse_size("512M"), 512ull << 20);
  EXPECT_EQ(parse_size("512MiB"), 512ull << 20);
  EXPECT_EQ(parse_size("1.5g"), 3ull << 29);
  EXPECT_EQ(parse_size("64k"), 64ull << 10);
}

TEST(ParseSize, RejectsGarbageAsUsageError) {
  for (const char* bad : {"", "G", "4X", "-1G", "0", "1.2.3M", "4 G"}) {
    try {
      parse_size(bad);
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const qemflow::Error& e) {
      EXPECT_EQ(e.kind(), qemflow::ErrorKind::usage) << bad;
      EXPECT_NE(std::string(e.what()).find("invalid size"), std::string::npos);
    }
  }
}

TEST(FormatSize, RoundTripsReadably) {
  EXPECT_EQ(format_size(256ull << 20), "256 MiB");
  EXPECT_EQ(format_size(3ull << 29), "1.5 GiB");
  EXPECT_EQ(format_size(12), "12 B");
}
