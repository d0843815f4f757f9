#include "io/ply_reader.hpp"

#include <algorithm>
#include <bit>
#include <charconv>
#include <limits>
#include <cmath>
#include <cstring>
#include <string_view>

#include "io/byte_source.hpp"
#include "io/ply_binary.hpp"
#include "io/ply_header.hpp"
#include "io/polygon_fan.hpp"
#include "util/error.hpp"

namespace qemflow::io {

namespace {

using namespace ply_binary;

class PlyReader final : public MeshReader {
 public:
  PlyReader(const std::filesystem::path& path, bool zstd) : source_(path, zstd) {
    header_ = read_ply_header(source_);
    line_ = header_.line_count + 1;
    token_line_ = line_;
    info_.format = header_.format;
    info_.zstd = zstd;
    info_.vertex_count = header_.elements[header_.vertex_element].count;
    info_.polygon_count = header_.face_element ? header_.elements[*header_.face_element].count : 0;
    info_.file_size = source_.file_size();
    vertex_count_ = *info_.vertex_count;
  }

  const MeshInfo& info() const override { return info_; }
  uint64_t bytes_read() const override { return source_.file_bytes_read(); }

  bool next(MeshBatch& batch, size_t max_elements) override {
    if (header_.format != MeshFormat::ply_ascii) return next_records(batch, max_elements);
    try {
      return next_records(batch, max_elements);
    } catch (const Error& e) {
      // The reader takes values wherever they are, so a line short of values (or with
      // too many) shows up records later, where the shifted values stop making sense:
      // the message names the first record that did not end on its own line too.
      if (ascii_misaligned_.empty() || e.kind() != ErrorKind::bad_input) throw;
      throw Error(e.kind(), std::string(e.what()) + " (" + ascii_misaligned_ +
                                ": a line with too few or too many values?)");
    }
  }

 private:
  bool next_records(MeshBatch& batch, size_t max_elements) {
    batch.clear();
    batch.first_vertex = vertices_out_;
    batch.first_triangle = triangles_out_;
    size_t budget = max_elements == 0 ? 1 : max_elements;
    while (element_ < header_.elements.size()) {
      const PlyElement& element = header_.elements[element_];
      if (done_ == element.count) {
        ++element_;
        done_ = 0;
        continue;
      }
      if (batch.vertices.size() + batch.triangles.size() >= budget) break;
      bool swap = header_.format == MeshFormat::ply_binary_be;
      bool ascii = header_.format == MeshFormat::ply_ascii;
      if (element_ == header_.vertex_element) {
        size_t before = batch.vertices.size();
        if (ascii) ascii_vertices(budget, batch);
        else if (swap) binary_vertices<true>(budget, batch);
        else binary_vertices<false>(budget, batch);
        vertices_out_ += batch.vertices.size() - before;
      } else if (header_.face_element && element_ == *header_.face_element) {
        size_t before = batch.triangles.size();
        if (ascii) ascii_faces(budget, batch);
        else if (swap) binary_faces<true>(budget, batch);
        else binary_faces<false>(budget, batch);
        triangles_out_ += batch.triangles.size() - before;
      } else {
        if (ascii) ascii_skip(element);
        else if (swap) binary_skip<true>(element);
        else binary_skip<false>(element);
      }
    }
    if (element_ == header_.elements.size() && !trailing_checked_) check_trailing();
    return !batch.vertices.empty() || !batch.triangles.empty();
  }

  // After the last element, whitespace at most (ply_binary::check_trailing_bytes).
  void check_trailing() {
    trailing_checked_ = true;
    const PlyElement& last = header_.elements.back();
    if (header_.format == MeshFormat::ply_ascii) {
      std::string_view token;
      begin_ascii_record(last, last.count);  // a token after the last record is no part of it
      if (next_token(token)) {
        throw_bad_input(name(), line_place(), data_after_last_element(last));
      }
      return;
    }
    while (source_.fill(1)) {
      check_trailing_bytes(name(), source_.data(), source_.available(), source_.offset(), last);
      source_.consume(source_.available());
    }
  }

  const std::string& name() const { return source_.name(); }
  std::string byte_place(uint64_t offset) const { return "byte " + std::to_string(offset); }
  std::string line_place() const { return "line " + std::to_string(token_line_); }
  std::string place(uint64_t offset) const {
    return header_.format == MeshFormat::ply_ascii ? line_place() : byte_place(offset);
  }

  std::string record_name(const PlyElement& element, uint64_t record) const {
    return element.name + " " + std::to_string(record) + " of " + std::to_string(element.count);
  }

  [[noreturn]] void truncated(const PlyElement& element, size_t needed) {
    std::string what = "file ends inside " + record_name(element, done_);
    if (header_.format != MeshFormat::ply_ascii) {
      what += " (needed " + std::to_string(needed) + " more bytes, found " +
              std::to_string(source_.available()) + ")";
    }
    throw_bad_input(name(), place(source_.offset()), what);
  }

  // A streamed polygon (ply_binary::streamed_polygon_vertices) cut by the end of the
  // file: the words truncated() would use had the whole record been asked for at once.
  [[noreturn]] void truncated_polygon(const PlyElement& element, size_t index_size) {
    const uint64_t read = polygon_length_ - polygon_left_ * index_size;
    throw_bad_input(name(), byte_place(polygon_offset_),
                    "file ends inside " + record_name(element, done_) + " (needed " +
                        std::to_string(polygon_length_) + " more bytes, found " +
                        std::to_string(read + source_.available()) + ")");
  }

  void check_vertex(const Point& p, uint64_t vertex, uint64_t offset) {
    if (!all_finite(p)) {
      throw_bad_input(name(), place(offset),
                      "vertex " + std::to_string(vertex) + " has a non-finite coordinate (" +
                          std::to_string(p[0]) + ", " + std::to_string(p[1]) + ", " +
                          std::to_string(p[2]) + ")");
    }
  }

  [[noreturn]] void bad_index(uint64_t face, int64_t index, uint64_t offset) {
    throw_bad_input(name(), place(offset),
                    "face " + std::to_string(face) + " has vertex index " + std::to_string(index) +
                        " but the file has " + std::to_string(vertex_count_) + " vertices");
  }

  void check_polygon_size(uint64_t face, int64_t count, uint64_t offset) {
    if (count < 3) {
      throw_bad_input(name(), place(offset),
                      "face " + std::to_string(face) + " has " + std::to_string(count) +
                          " vertices (a face needs at least 3)");
    }
  }

  bool full(const MeshBatch& batch, size_t budget) const {
    return batch.vertices.size() + batch.triangles.size() >= budget;
  }
  auto emit_into(MeshBatch& batch) {
    return [&batch](uint64_t a, uint64_t b, uint64_t c) { batch.triangles.push_back({a, b, c}); };
  }
  // Checks `count` binary indices at `indices` and adds them to fan_, its triangles
  // into the batch; `offset` is their record's, for errors.
  template <bool Swap>
  void fan_indices(PlyType type, const char* indices, size_t count, uint64_t offset, MeshBatch& batch) {
    const size_t index_size = size_of(type);
    for (size_t i = 0; i < count; ++i) {
      int64_t index = load_integer<Swap>(type, indices + i * index_size);
      if (index < 0 || static_cast<uint64_t>(index) >= vertex_count_) bad_index(done_, index, offset);
      fan_.add(static_cast<uint64_t>(index), emit_into(batch));
    }
  }

  template <bool Swap>
  size_t binary_record_length(const PlyElement& element, const char* p, size_t available,
                              size_t& needed, size_t* list_offset = nullptr,
                              size_t list_property = SIZE_MAX) {
    return record_length<Swap>(element, p, available, needed, list_offset, list_property,
                               [&](const std::string& problem) {
                                 throw_bad_input(name(), byte_place(source_.offset() + (p - source_.data())),
                                                 element.name + " " + std::to_string(done_) + " " + problem);
                               });
  }

  template <bool Swap>
  void binary_skip(const PlyElement& element) {
    size_t record = element.fixed_record_size();
    while (done_ < element.count) {
      if (record > 0 || element.properties.empty()) {
        if (record == 0) {
          done_ = element.count;
          return;
        }
        if (!source_.fill(record)) truncated(element, record);
        uint64_t fit = std::min<uint64_t>(element.count - done_, source_.available() / record);
        source_.consume(fit * record);
        done_ += fit;
        continue;
      }
      size_t needed = 0;
      size_t length = binary_record_length<Swap>(element, source_.data(), source_.available(), needed);
      if (length == 0) {
        if (!source_.fill(needed)) truncated(element, needed);
        continue;
      }
      source_.consume(length);
      ++done_;
    }
  }

  template <bool Swap>
  void binary_vertices(size_t budget, MeshBatch& batch) {
    const PlyElement& element = header_.elements[header_.vertex_element];
    const VertexLayout layout = vertex_layout(header_);
    const size_t record = layout.record;
    while (done_ < element.count && batch.vertices.size() < budget) {
      if (record == 0) {
        // Lists in the vertex element: walk record by record; lists come after
        // scalars only if the header says so, so offsets are recomputed per record.
        binary_vertex_with_lists<Swap>(element, batch);
        continue;
      }
      if (!source_.fill(record)) truncated(element, record);
      size_t fit = std::min<uint64_t>({element.count - done_, source_.available() / record,
                                       budget - batch.vertices.size()});
      size_t base = batch.vertices.size();
      batch.vertices.resize(base + fit);
      Point* out = batch.vertices.data() + base;
      decode_vertex_records<Swap>(layout, source_.data(), fit, out);
      for (size_t i = 0; i < fit; ++i) {
        if (!all_finite(out[i])) check_vertex(out[i], done_ + i, source_.offset() + i * record);
      }
      source_.consume(fit * record);
      done_ += fit;
    }
  }

  template <bool Swap>
  void binary_vertex_with_lists(const PlyElement& element, MeshBatch& batch) {
    size_t needed = 0;
    size_t length = binary_record_length<Swap>(element, source_.data(), source_.available(), needed);
    if (length == 0) {
      if (!source_.fill(needed)) truncated(element, needed);
      return;
    }
    const char* p = source_.data();
    Point point{};
    size_t position = 0;
    for (size_t i = 0; i < element.properties.size(); ++i) {
      const PlyProperty& property = element.properties[i];
      if (property.is_list) {
        int64_t count = load_integer<Swap>(property.count_type, p + position);
        position += size_of(property.count_type) + count * size_of(property.type);
        continue;
      }
      for (int axis = 0; axis < 3; ++axis) {
        if (header_.coordinate_property[axis] == i) point[axis] = load_real<Swap>(property.type, p + position);
      }
      position += size_of(property.type);
    }
    check_vertex(point, done_, source_.offset());
    batch.vertices.push_back(point);
    source_.consume(length);
    ++done_;
  }

  template <bool Swap>
  void binary_faces(size_t budget, MeshBatch& batch) {
    const PlyElement& element = header_.elements[*header_.face_element];
    const PlyProperty& list = element.properties[header_.index_property];
    const bool only_list = element.properties.size() == 1;
    const size_t count_size = size_of(list.count_type);
    const size_t index_size = size_of(list.type);
    const PlyType count_type = list.count_type;
    const PlyType index_type = list.type;
    const bool uchar_int = count_type == PlyType::uint8 &&
                           (index_type == PlyType::int32 || index_type == PlyType::uint32);
    batch.triangles.reserve(budget);
    while (done_ < element.count && batch.vertices.size() + batch.triangles.size() < budget) {
      const char* p = source_.data();
      const size_t available = source_.available();
      size_t used = 0;
      size_t needed = 0;
      while (done_ < element.count && batch.vertices.size() + batch.triangles.size() < budget) {
        const char* record = p + used;
        const size_t left = available - used;
        if (polygon_left_ > 0) {  // a streamed polygon: its indices as far as they are here
          const size_t fit = std::min<uint64_t>({polygon_left_, left / index_size,
                                                 budget - batch.vertices.size() - batch.triangles.size()});
          if (fit == 0) {
            needed = index_size;
            break;
          }
          fan_indices<Swap>(index_type, record, fit, polygon_offset_, batch);
          used += fit * index_size;
          polygon_left_ -= fit;
          if (polygon_left_ == 0) {
            fan_.reset();
            ++done_;
          }
          continue;
        }
        // The common layout: "list uchar int" and triangles only.
        if (only_list && uchar_int && left >= 13 && static_cast<uint8_t>(*record) == 3) {
          uint32_t a = load32<Swap>(record + 1), b = load32<Swap>(record + 5), c = load32<Swap>(record + 9);
          // For signed int, negative values become huge as uint32 and fail this test too.
          if (a >= vertex_count_ || b >= vertex_count_ || c >= vertex_count_) {
            uint32_t bad = a >= vertex_count_ ? a : b >= vertex_count_ ? b : c;
            int64_t shown = index_type == PlyType::int32 ? int64_t{static_cast<int32_t>(bad)} : int64_t{bad};
            bad_index(done_, shown, source_.offset() + used);
          }
          batch.triangles.push_back({a, b, c});
          used += 13;
          ++done_;
          continue;
        }
        size_t list_offset = 0;
        size_t length;
        if (only_list) {
          if (left < count_size) {
            needed = count_size;
            break;
          }
          int64_t count = load_integer<Swap>(count_type, record);
          check_polygon_size(done_, count, source_.offset() + used);
          length = count_size + static_cast<size_t>(count) * index_size;
          if (length > max_record_bytes) {
            throw_bad_input(name(), byte_place(source_.offset() + used),
                            "face " + std::to_string(done_) + " has an implausible " +
                                std::to_string(count) + " vertices");
          }
          if (count >= int64_t{streamed_polygon_vertices}) {
            polygon_left_ = static_cast<uint64_t>(count);
            polygon_offset_ = source_.offset() + used;
            polygon_length_ = length;
            used += count_size;
            continue;
          }
          if (left < length) {
            needed = length;
            break;
          }
        } else {
          length = binary_record_length<Swap>(element, record, left, needed, &list_offset,
                                              header_.index_property);
          if (length == 0) break;
        }
        int64_t count = load_integer<Swap>(count_type, record + list_offset);
        check_polygon_size(done_, count, source_.offset() + used);
        const char* indices = record + list_offset + count_size;
        fan_indices<Swap>(index_type, indices, static_cast<size_t>(count), source_.offset() + used, batch);
        fan_.reset();
        used += length;
        ++done_;
      }
      source_.consume(used);
      if (needed > 0 && !source_.fill(needed)) {
        if (polygon_left_ > 0) truncated_polygon(element, index_size);
        truncated(element, needed);
      }
    }
  }

  // ---- ascii ----

  // Next whitespace-separated token; false at end of file. The view is valid until
  // the next call.
  bool next_token(std::string_view& token) {
    for (;;) {
      if (!source_.fill(1)) return false;
      const char* p = source_.data();
      size_t n = source_.available();
      size_t i = 0;
      while (i < n && is_space(p[i])) {
        if (p[i] == '\n') ++line_;
        ++i;
      }
      source_.consume(i);
      if (i < n) break;
    }
    size_t scanned = 0;
    for (;;) {
      const char* p = source_.data();
      size_t n = source_.available();
      size_t i = scanned;
      while (i < n && !is_space(p[i])) ++i;
      if (i == n) {
        if (n > 4096) throw_bad_input(name(), line_place(), "token is too long");
        if (source_.fill(n + 1)) {
          scanned = n;
          continue;
        }
        p = source_.data();
        i = source_.available();
      }
      token = std::string_view(p, i);
      token_line_ = line_;
      note_ascii_record_line();
      source_.consume(i);
      return true;
    }
  }

  // An ascii record is one line. The first record found on more than one line is
  // remembered for the error messages (ascii_misaligned_); reading goes on, as other
  // readers' does.
  void begin_ascii_record(const PlyElement& element, uint64_t index) {
    record_element_ = &element;
    record_index_ = index;
    record_line_ = 0;
  }
  void note_ascii_record_line() {
    if (record_line_ == 0) {
      record_line_ = token_line_;
    } else if (token_line_ != record_line_ && ascii_misaligned_.empty() && record_element_) {
      ascii_misaligned_ = record_name(*record_element_, record_index_) + " starts on line " +
                          std::to_string(record_line_) + " and ends on line " + std::to_string(token_line_);
    }
  }

  std::string_view expect_token(const PlyElement& element) {
    std::string_view token;
    if (!next_token(token)) truncated(element, 0);
    return token;
  }

  int64_t parse_integer(std::string_view token, const char* what) {
    if (!token.empty() && token[0] == '+') token.remove_prefix(1);
    int64_t value = 0;
    auto [end, error] = std::from_chars(token.data(), token.data() + token.size(), value);
    if (error != std::errc() || end != token.data() + token.size()) {
      throw_bad_input(name(), line_place(),
                      std::string(what) + " '" + std::string(token) + "' is not an integer");
    }
    return value;
  }

  double parse_real(std::string_view token, const char* what) {
    if (!token.empty() && token[0] == '+') token.remove_prefix(1);
    double value = 0;
    auto [end, error] = std::from_chars(token.data(), token.data() + token.size(), value);
    if (error == std::errc::result_out_of_range) return std::numeric_limits<double>::infinity();
    if (error != std::errc() || end != token.data() + token.size()) {
      throw_bad_input(name(), line_place(),
                      std::string(what) + " '" + std::string(token) + "' is not a number");
    }
    return value;
  }

  int64_t ascii_list_count(const PlyElement& element, const PlyProperty& property) {
    int64_t count = parse_integer(expect_token(element), "list count");
    if (count < 0 || count > int64_t{1} << 24) {
      throw_bad_input(name(), line_place(),
                      element.name + " " + std::to_string(done_) + " has an invalid list count " +
                          std::to_string(count) + " for '" + property.name + "'");
    }
    return count;
  }

  void ascii_skip_property(const PlyElement& element, const PlyProperty& property) {
    if (!property.is_list) {
      expect_token(element);
      return;
    }
    int64_t count = ascii_list_count(element, property);
    for (int64_t i = 0; i < count; ++i) expect_token(element);
  }

  void ascii_skip(const PlyElement& element) {
    for (; done_ < element.count; ++done_) {
      begin_ascii_record(element, done_);
      for (const auto& property : element.properties) ascii_skip_property(element, property);
    }
  }

  void ascii_vertices(size_t budget, MeshBatch& batch) {
    const PlyElement& element = header_.elements[header_.vertex_element];
    while (done_ < element.count && batch.vertices.size() < budget) {
      begin_ascii_record(element, done_);
      Point point{};
      for (size_t i = 0; i < element.properties.size(); ++i) {
        const PlyProperty& property = element.properties[i];
        int axis = -1;
        for (int a = 0; a < 3; ++a) {
          if (header_.coordinate_property[a] == i) axis = a;
        }
        if (axis < 0) {
          ascii_skip_property(element, property);
          continue;
        }
        point[axis] = parse_real(expect_token(element), "coordinate");
      }
      check_vertex(point, done_, 0);
      batch.vertices.push_back(point);
      ++done_;
    }
  }

  // A face's triangles go out as its indices are parsed, so a polygon may be cut by
  // the batch's end: the next call resumes at property ascii_property_, inside the list
  // when polygon_left_ says so.
  void ascii_faces(size_t budget, MeshBatch& batch) {
    const PlyElement& element = header_.elements[*header_.face_element];
    while (done_ < element.count && (ascii_property_ > 0 || !full(batch, budget))) {
      if (ascii_property_ == 0 && !in_list_) begin_ascii_record(element, done_);
      for (; ascii_property_ < element.properties.size(); ++ascii_property_) {
        const PlyProperty& property = element.properties[ascii_property_];
        if (ascii_property_ != header_.index_property) {
          ascii_skip_property(element, property);
          continue;
        }
        if (!in_list_) {
          int64_t count = ascii_list_count(element, property);
          check_polygon_size(done_, count, 0);
          polygon_left_ = static_cast<uint64_t>(count);
          in_list_ = true;
        }
        for (; polygon_left_ > 0; --polygon_left_) {
          if (full(batch, budget)) return;
          int64_t index = parse_integer(expect_token(element), "vertex index");
          if (index < 0 || static_cast<uint64_t>(index) >= vertex_count_) bad_index(done_, index, 0);
          fan_.add(static_cast<uint64_t>(index), emit_into(batch));
        }
        in_list_ = false;
      }
      fan_.reset();
      ascii_property_ = 0;
      ++done_;
    }
  }

  ByteSource source_;
  PlyHeader header_;
  MeshInfo info_;
  bool trailing_checked_ = false;
  uint64_t vertex_count_ = 0;
  size_t element_ = 0;     // element being read
  uint64_t done_ = 0;      // records of it already read
  uint64_t line_ = 0;      // ascii: current line
  uint64_t token_line_ = 0;  // ascii: line of the last token read (what errors name)
  // ascii: the record being read, the line of its first token (0: none read yet), and
  // the first record that was not on one line ("" while none).
  const PlyElement* record_element_ = nullptr;
  uint64_t record_index_ = 0;
  uint64_t record_line_ = 0;
  std::string ascii_misaligned_;
  uint64_t vertices_out_ = 0;
  uint64_t triangles_out_ = 0;
  // The polygon being read: its fan, and for one cut by a batch's end (ascii) or
  // streamed (binary), the indices still to read.
  PolygonFan fan_;
  uint64_t polygon_left_ = 0;
  uint64_t polygon_offset_ = 0;  // binary: the record's offset and length, for errors
  uint64_t polygon_length_ = 0;
  size_t ascii_property_ = 0;    // ascii: the face property to read next
  bool in_list_ = false;         // ascii: its list count has been read
};

}  // namespace

std::unique_ptr<MeshReader> open_ply_reader(const std::filesystem::path& path, bool zstd) {
  return std::make_unique<PlyReader>(path, zstd);
}

}  // namespace qemflow::io
