#include "io/obj_reader.hpp"

#include <charconv>
#include <cstring>
#include <limits>
#include <string>
#include <string_view>

#include "io/byte_source.hpp"
#include "io/polygon_fan.hpp"
#include "util/error.hpp"

namespace qemflow::io {

namespace {

constexpr size_t max_line_bytes = size_t{16} << 20;

inline bool is_blank(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }

class ObjReader final : public MeshReader {
 public:
  ObjReader(const std::filesystem::path& path, bool zstd) : source_(path, zstd) {
    info_.format = MeshFormat::obj;
    info_.zstd = zstd;
    info_.file_size = source_.file_size();
  }

  const MeshInfo& info() const override { return info_; }
  uint64_t bytes_read() const override { return source_.file_bytes_read(); }

  bool next(MeshBatch& batch, size_t max_elements) override {
    batch.clear();
    batch.first_vertex = vertex_count_;
    batch.first_triangle = triangle_count_;
    size_t budget = max_elements == 0 ? 1 : max_elements;
    if (!face_rest_.empty() || fan_.seen > 0) face(batch, budget);
    std::string_view line;
    while (batch.vertices.size() + batch.triangles.size() < budget && fan_.seen == 0 && next_line(line)) {
      size_t i = 0;
      while (i < line.size() && is_blank(line[i])) ++i;
      line.remove_prefix(i);
      if (line.size() < 2 || !is_blank(line[1])) continue;  // vt, vn, g, #, blank, ...
      if (line[0] == 'v') {
        batch.vertices.push_back(parse_vertex(line.substr(2)));
        ++vertex_count_;
      } else if (line[0] == 'f') {
        face_rest_ = line.substr(2);
        face(batch, budget);
      }
    }
    return !batch.vertices.empty() || !batch.triangles.empty();
  }

 private:
  [[noreturn]] void fail(const std::string& problem) const {
    throw_bad_input(source_.name(), "line " + std::to_string(line_), problem);
  }

  bool next_line(std::string_view& line) {
    size_t scanned = 0;
    for (;;) {
      const char* data = source_.data();
      size_t available = source_.available();
      const void* newline = std::memchr(data + scanned, '\n', available - scanned);
      if (newline) {
        size_t length = static_cast<const char*>(newline) - data;
        line = std::string_view(data, length);
        source_.consume(length + 1);
        break;
      }
      scanned = available;
      if (scanned > max_line_bytes) {
        ++line_;
        fail("line is longer than " + std::to_string(max_line_bytes) + " bytes");
      }
      if (!source_.fill(scanned + 1)) {
        if (source_.available() == 0) return false;
        line = std::string_view(source_.data(), source_.available());
        source_.consume(source_.available());
        break;
      }
    }
    ++line_;
    return true;
  }

  static std::string_view next_word(std::string_view& rest) {
    size_t i = 0;
    while (i < rest.size() && is_blank(rest[i])) ++i;
    size_t start = i;
    while (i < rest.size() && !is_blank(rest[i])) ++i;
    std::string_view word = rest.substr(start, i - start);
    rest.remove_prefix(i);
    return word;
  }

  Point parse_vertex(std::string_view rest) {
    Point point{};
    for (int axis = 0; axis < 3; ++axis) {
      std::string_view word = next_word(rest);
      if (word.empty()) fail("vertex " + std::to_string(vertex_count_) + " has fewer than 3 coordinates");
      if (word[0] == '+') word.remove_prefix(1);
      auto [end, error] = std::from_chars(word.data(), word.data() + word.size(), point[axis]);
      if (error == std::errc::result_out_of_range) {
        point[axis] = std::numeric_limits<double>::infinity();
      } else if (error != std::errc() || end != word.data() + word.size()) {
        fail("vertex " + std::to_string(vertex_count_) + " has coordinate '" + std::string(word) +
             "' which is not a number");
      }
    }
    double zero = (point[0] - point[0]) + (point[1] - point[1]) + (point[2] - point[2]);
    if (!(zero == 0)) fail("vertex " + std::to_string(vertex_count_) + " has a non-finite coordinate");
    return point;
  }

  // Reads the face in face_rest_, its triangles going into the batch until it is full;
  // a face cut there stays in face_rest_ and fan_ for the next batch. face_rest_ views
  // the source's buffer, which keeps it: no fill() runs until the face is done.
  void face(MeshBatch& batch, size_t budget) {
    for (;;) {
      std::string_view rest = face_rest_;
      std::string_view word = next_word(rest);
      if (word.empty()) break;
      if (batch.vertices.size() + batch.triangles.size() >= budget) return;
      face_rest_ = rest;
      // v, v/vt, v//vn, v/vt/vn: only the part before the first slash matters.
      std::string_view number = word.substr(0, word.find('/'));
      int64_t index = 0;
      auto [end, error] = std::from_chars(number.data(), number.data() + number.size(), index);
      if (error != std::errc() || end != number.data() + number.size() || index == 0) {
        fail("face " + std::to_string(face_count_) + " has vertex reference '" + std::string(word) +
             "' which is not a non-zero integer");
      }
      int64_t resolved = index > 0 ? index - 1 : static_cast<int64_t>(vertex_count_) + index;
      if (resolved < 0 || static_cast<uint64_t>(resolved) >= vertex_count_) {
        fail("face " + std::to_string(face_count_) + " has vertex index " + std::to_string(index) +
             " but only " + std::to_string(vertex_count_) + " vertices are defined before it");
      }
      fan_.add(static_cast<uint64_t>(resolved), [&](uint64_t a, uint64_t b, uint64_t c) {
        batch.triangles.push_back({a, b, c});
        ++triangle_count_;
      });
    }
    if (fan_.seen < 3) {
      fail("face " + std::to_string(face_count_) + " has " + std::to_string(fan_.seen) +
           " vertices (a face needs at least 3)");
    }
    face_rest_ = {};
    fan_.reset();
    ++face_count_;
  }

  ByteSource source_;
  MeshInfo info_;
  uint64_t line_ = 0;
  uint64_t vertex_count_ = 0;
  uint64_t triangle_count_ = 0;
  uint64_t face_count_ = 0;
  std::string_view face_rest_;  // the unread part of a face cut by a batch's end
  PolygonFan fan_;
};

}  // namespace

std::unique_ptr<MeshReader> open_obj_reader(const std::filesystem::path& path, bool zstd) {
  return std::make_unique<ObjReader>(path, zstd);
}

}  // namespace qemflow::io
