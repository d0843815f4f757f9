#pragma once
// Writes PLY files byte by byte for tests: any encoding, any property types, extra
// properties and elements, so the reader meets layouts our own writer never makes.
#include <zstd.h>

#include <cstdint>
#include <string>
#include <vector>

#include "io_test_support.hpp"

namespace qemflow::io::testing {

class PlyBuilder {
 public:
  // format: "ascii", "binary_little_endian" or "binary_big_endian".
  explicit PlyBuilder(std::string format) : format_(std::move(format)) {
    header_ = "ply\nformat " + format_ + " 1.0\ncomment made by PlyBuilder\n";
  }

  void header_line(const std::string& line) { header_ += line + "\n"; }

  // Appends one value of PLY type `type` to the body.
  void value(const std::string& type, double v) {
    if (format_ == "ascii") {
      char text[64];
      if (type == "float" || type == "float32" || type == "double" || type == "float64") {
        std::snprintf(text, sizeof text, "%.17g ", v);
      } else {
        std::snprintf(text, sizeof text, "%lld ", static_cast<long long>(v));
      }
      body_ += text;
      return;
    }
    bool be = format_ == "binary_big_endian";
    if (type == "char" || type == "int8") put(body_, static_cast<int8_t>(v), be);
    else if (type == "uchar" || type == "uint8") put(body_, static_cast<uint8_t>(v), be);
    else if (type == "short" || type == "int16") put(body_, static_cast<int16_t>(v), be);
    else if (type == "ushort" || type == "uint16") put(body_, static_cast<uint16_t>(v), be);
    else if (type == "int" || type == "int32") put(body_, static_cast<int32_t>(v), be);
    else if (type == "uint" || type == "uint32") put(body_, static_cast<uint32_t>(v), be);
    else if (type == "float" || type == "float32") put(body_, static_cast<float>(v), be);
    else put(body_, v, be);
  }

  void end_record() {
    if (format_ == "ascii") body_ += "\n";
  }

  void raw(const std::string& bytes) { body_ += bytes; }

  std::string header() const { return header_ + "end_header\n"; }
  std::string bytes() const { return header() + body_; }
  size_t body_size() const { return body_.size(); }

 private:
  std::string format_;
  std::string header_;
  std::string body_;
};

inline std::string zstd_compress(const std::string& bytes) {
  std::string out(ZSTD_compressBound(bytes.size()), '\0');
  size_t n = ZSTD_compress(out.data(), out.size(), bytes.data(), bytes.size(), 3);
  out.resize(n);
  return out;
}

}  // namespace qemflow::io::testing
