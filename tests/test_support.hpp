#pragma once
// Helpers shared by every test suite.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>

namespace qemflow::testing {

// ../shared/data beside the repository; tests that need it call GTEST_SKIP when absent.
inline std::filesystem::path shared_data_dir() { return QEMFLOW_SHARED_DATA; }
inline std::filesystem::path shared_mesh(const std::string& name) {
  return shared_data_dir() / (name + ".ply.zst");
}
#define QEMFLOW_REQUIRE_SHARED_MESH(path)                                          \
  do {                                                                             \
    if (!std::filesystem::exists(path)) GTEST_SKIP() << "no " << (path).string(); \
  } while (0)

inline std::filesystem::path cli_path() { return QEMFLOW_CLI; }

// A file's whole contents (to compare outputs byte for byte).
inline std::string file_bytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A fresh directory removed when the object dies.
class TempDir {
 public:
  TempDir() {
    std::random_device rd;
    path_ = std::filesystem::temp_directory_path() /
            ("qemflow-test-" + std::to_string(rd()) + std::to_string(rd()));
    std::filesystem::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

// Runs a shell command, returns its exit status (0..255), stdout+stderr in `output`.
inline int run_command(const std::string& command, std::string* output = nullptr) {
  std::string full = command + " 2>&1";
  FILE* pipe = popen(full.c_str(), "r");
  if (!pipe) return -1;
  std::string text;
  char buffer[4096];
  size_t n;
  while ((n = fread(buffer, 1, sizeof buffer, pipe)) > 0) text.append(buffer, n);
  int status = pclose(pipe);
  if (output) *output = text;
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

}  // namespace qemflow::testing
