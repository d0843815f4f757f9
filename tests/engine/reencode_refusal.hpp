#pragma once
// The re-encode of a bad input, resident and with the out-of-core dereference forced:
// each must end with a bad_input error and leave no output and an empty scratch dir.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "engine/governor.hpp"
#include "engine/reencode.hpp"
#include "util/error.hpp"

namespace qemflow::engine::testing {

// `check` sees each run's error, e.g. to compare its message.
template <class Check>
void expect_reencode_refused(const std::filesystem::path& input, const std::filesystem::path& output,
                             const std::filesystem::path& scratch_dir, Check check) {
  for (bool out_of_core : {false, true}) {
    SCOPED_TRACE(out_of_core ? "out of core" : "resident");
    Governor governor(64ull << 20, 0);
    ReencodeOptions options{.input = input, .output = output, .scratch_dir = scratch_dir};
    options.load.force_out_of_core = out_of_core;
    try {
      run_reencode(governor, options, {});
      ADD_FAILURE() << "accepted";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::bad_input) << e.what();
      check(e);
    }
    EXPECT_FALSE(std::filesystem::exists(output));
    EXPECT_TRUE(std::filesystem::is_empty(scratch_dir));
  }
}

}  // namespace qemflow::engine::testing
