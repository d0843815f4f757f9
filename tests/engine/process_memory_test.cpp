// tune_allocator's huge-page advice: big allocations through the CLI's operator new
// (apps/qemflow/huge_page_new.cpp, linked into this test too) are advised before they
// are touched, only when asked for (the out-of-core simplify's setting).
#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <new>
#include <sstream>
#include <string>

#include "engine/process_memory.hpp"

namespace qemflow::engine {
namespace {

// The VmFlags of the mapping holding `address`, from /proc/self/smaps.
std::string vm_flags_at(const void* address) {
  std::ifstream smaps("/proc/self/smaps");
  std::string line;
  bool inside = false;
  const uintptr_t a = uintptr_t(address);
  while (std::getline(smaps, line)) {
    uintptr_t from = 0, to = 0;
    char dash = 0;
    std::istringstream range(line);
    if (range >> std::hex >> from >> dash >> to && dash == '-' && line.find(':') > line.find(' ')) {
      inside = from <= a && a < to;
      continue;
    }
    if (inside && line.rfind("VmFlags:", 0) == 0) return line;
  }
  return {};
}

bool has_flag(const std::string& flags, const std::string& flag) {
  std::istringstream words(flags);
  for (std::string word; words >> word;)
    if (word == flag) return true;
  return false;
}

TEST(ProcessMemory, HugePagesAreAdvisedOnBigAllocationsOnlyWhenAsked) {
  if (!std::filesystem::exists("/sys/kernel/mm/transparent_hugepage/enabled"))
    GTEST_SKIP() << "no transparent huge pages";
  constexpr size_t kBig = 16u << 20;
  tune_allocator(8 << 20, 1, 2 << 20, true);
  EXPECT_TRUE(huge_pages_on_big_allocations());
  {
    std::unique_ptr<char[]> big(new char[kBig]);
    std::unique_ptr<char[]> small(new char[1u << 20]);  // below the mmap threshold: the heap, no advice
    EXPECT_TRUE(has_flag(vm_flags_at(big.get() + kBig / 2), "hg")) << vm_flags_at(big.get() + kBig / 2);
    EXPECT_FALSE(has_flag(vm_flags_at(small.get()), "hg")) << vm_flags_at(small.get());
  }
  tune_allocator();  // the defaults: no advice
  EXPECT_FALSE(huge_pages_on_big_allocations());
  std::unique_ptr<char[]> plain(new char[kBig]);
  EXPECT_FALSE(has_flag(vm_flags_at(plain.get() + kBig / 2), "hg")) << vm_flags_at(plain.get() + kBig / 2);
}

// review17 (MEDIUM): the replacement operator new must keep the standard's required
// behaviour ([new.delete.single]): when the allocation fails it calls the current
// new_handler (a host's: free a cache, an emergency reserve) before throwing. It threw
// bad_alloc at once; libstdc++'s own operator new calls the handler.
int new_handler_calls = 0;
TEST(ProcessMemory, OperatorNewCallsTheNewHandlerBeforeThrowing) {
  new_handler_calls = 0;
  const std::new_handler before = std::set_new_handler([] {
    ++new_handler_calls;
    std::set_new_handler(nullptr);  // the next failure throws
  });
  volatile size_t impossible = SIZE_MAX / 4;  // malloc fails whatever the machine
  void* p = nullptr;
  bool threw = false;
  try {
    p = ::operator new(impossible);
  } catch (const std::bad_alloc&) {
    threw = true;
  }
  ::operator delete(p);
  std::set_new_handler(before);
  EXPECT_TRUE(threw);
  EXPECT_EQ(new_handler_calls, 1);
}

}  // namespace
}  // namespace qemflow::engine
