#include "io/ply_header.hpp"

#include <charconv>
#include <cstring>
#include <string_view>

#include "io/byte_source.hpp"
#include "util/error.hpp"

namespace qemflow::io {

namespace {

struct TypeName {
  const char* name;
  PlyType type;
};
constexpr TypeName type_names[] = {
    {"char", PlyType::int8},     {"int8", PlyType::int8},       {"uchar", PlyType::uint8},
    {"uint8", PlyType::uint8},   {"short", PlyType::int16},     {"int16", PlyType::int16},
    {"ushort", PlyType::uint16}, {"uint16", PlyType::uint16},   {"int", PlyType::int32},
    {"int32", PlyType::int32},   {"uint", PlyType::uint32},     {"uint32", PlyType::uint32},
    {"float", PlyType::float32}, {"float32", PlyType::float32}, {"double", PlyType::float64},
    {"float64", PlyType::float64},
};

std::vector<std::string_view> split_words(std::string_view line) {
  std::vector<std::string_view> words;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t') ++i;
    if (i > start) words.push_back(line.substr(start, i - start));
  }
  return words;
}

class HeaderParser {
 public:
  explicit HeaderParser(ByteSource& source) : source_(source) {}

  PlyHeader parse() {
    std::string_view first;
    if (!next_line(first) || first != "ply") {
      fail(1, "not a PLY file (the first line must be 'ply')");
    }
    bool have_format = false;
    for (;;) {
      std::string_view line;
      if (!next_line(line)) fail(line_, "header has no end_header line");
      auto words = split_words(line);
      if (words.empty()) continue;
      std::string_view keyword = words[0];
      if (keyword == "comment" || keyword == "obj_info") continue;
      if (keyword == "end_header") break;
      if (keyword == "format") {
        parse_format(words);
        have_format = true;
      } else if (keyword == "element") {
        parse_element(words);
      } else if (keyword == "property") {
        parse_property(words);
      } else {
        fail(line_, "unknown header keyword '" + std::string(keyword) + "'");
      }
    }
    if (!have_format) fail(line_, "header has no format line");
    header_.line_count = line_;
    header_.byte_count = source_.offset();
    resolve_roles();
    return std::move(header_);
  }

 private:
  // Header lines end in \n (or \r\n); one line may not exceed 64 KiB.
  bool next_line(std::string_view& line) {
    constexpr size_t max_line = 64 << 10;
    size_t scanned = 0;
    for (;;) {
      const char* data = source_.data();
      const void* newline = std::memchr(data + scanned, '\n', source_.available() - scanned);
      if (newline) {
        size_t length = static_cast<const char*>(newline) - data;
        line_text_.assign(data, length);
        source_.consume(length + 1);
        break;
      }
      scanned = source_.available();
      if (scanned > max_line) fail(line_ + 1, "header line is too long (is this a PLY file?)");
      if (!source_.fill(scanned + 1)) {
        if (source_.available() == 0) return false;
        line_text_.assign(source_.data(), source_.available());
        source_.consume(source_.available());
        break;
      }
    }
    ++line_;
    if (!line_text_.empty() && line_text_.back() == '\r') line_text_.pop_back();
    line = line_text_;
    return true;
  }

  [[noreturn]] void fail(uint64_t line, const std::string& problem) {
    throw_bad_input(source_.name(), "line " + std::to_string(line), problem);
  }

  void parse_format(const std::vector<std::string_view>& words) {
    if (words.size() != 3) fail(line_, "format line must be 'format ENCODING 1.0'");
    if (words[1] == "ascii") {
      header_.format = MeshFormat::ply_ascii;
    } else if (words[1] == "binary_little_endian") {
      header_.format = MeshFormat::ply_binary_le;
    } else if (words[1] == "binary_big_endian") {
      header_.format = MeshFormat::ply_binary_be;
    } else {
      fail(line_, "unknown PLY format '" + std::string(words[1]) + "'");
    }
    if (words[2] != "1.0" && words[2] != "1") {
      fail(line_, "unsupported PLY version '" + std::string(words[2]) + "'");
    }
  }

  void parse_element(const std::vector<std::string_view>& words) {
    if (words.size() != 3) fail(line_, "element line must be 'element NAME COUNT'");
    PlyElement element;
    element.name = std::string(words[1]);
    element.line = line_;
    auto count = words[2];
    auto [end, error] = std::from_chars(count.data(), count.data() + count.size(), element.count);
    if (error != std::errc() || end != count.data() + count.size()) {
      fail(line_, "element count '" + std::string(count) + "' is not a non-negative integer");
    }
    for (const auto& other : header_.elements) {
      if (other.name == element.name) fail(line_, "element '" + element.name + "' declared twice");
    }
    header_.elements.push_back(std::move(element));
  }

  PlyType parse_type(std::string_view word) {
    auto type = parse_ply_type(word);
    if (!type) fail(line_, "unknown property type '" + std::string(word) + "'");
    return *type;
  }

  void parse_property(const std::vector<std::string_view>& words) {
    if (header_.elements.empty()) fail(line_, "property before any element");
    PlyProperty property;
    if (words.size() >= 2 && words[1] == "list") {
      if (words.size() != 5) fail(line_, "list property must be 'property list COUNT_TYPE TYPE NAME'");
      property.is_list = true;
      property.count_type = parse_type(words[2]);
      property.type = parse_type(words[3]);
      property.name = std::string(words[4]);
      if (!is_integer(property.count_type)) {
        fail(line_, "list count type '" + std::string(words[2]) + "' is not an integer type");
      }
    } else {
      if (words.size() != 3) fail(line_, "property line must be 'property TYPE NAME'");
      property.type = parse_type(words[1]);
      property.name = std::string(words[2]);
    }
    auto& element = header_.elements.back();
    for (const auto& other : element.properties) {
      if (other.name == property.name) {
        fail(line_, "property '" + property.name + "' declared twice in element '" + element.name + "'");
      }
    }
    element.properties.push_back(std::move(property));
  }

  void resolve_roles() {
    auto& elements = header_.elements;
    std::optional<size_t> vertex;
    for (size_t e = 0; e < elements.size(); ++e) {
      if (elements[e].name == "vertex") vertex = e;
      if (elements[e].name == "face") header_.face_element = e;
    }
    if (!vertex) fail(header_.line_count, "header declares no 'vertex' element");
    header_.vertex_element = *vertex;
    const PlyElement& vertices = elements[*vertex];
    const char* axes[3] = {"x", "y", "z"};
    for (int axis = 0; axis < 3; ++axis) {
      bool found = false;
      for (size_t p = 0; p < vertices.properties.size(); ++p) {
        const auto& property = vertices.properties[p];
        if (property.name != axes[axis]) continue;
        if (property.is_list) {
          fail(vertices.line, std::string("vertex property '") + axes[axis] +
                                  "' is a list; a coordinate must be a scalar");
        }
        header_.coordinate_property[axis] = p;
        found = true;
      }
      if (!found) fail(vertices.line, std::string("vertex element has no '") + axes[axis] + "' property");
    }
    if (!header_.face_element) return;
    const PlyElement& faces = elements[*header_.face_element];
    if (*header_.face_element < *vertex) {
      fail(faces.line, "the face element comes before the vertex element (not supported for streaming)");
    }
    bool found = false;
    for (size_t p = 0; p < faces.properties.size(); ++p) {
      const auto& property = faces.properties[p];
      if (property.name != "vertex_indices" && property.name != "vertex_index") continue;
      if (!property.is_list) fail(faces.line, "face property '" + property.name + "' is not a list");
      if (!is_integer(property.type)) {
        fail(faces.line, "face property '" + property.name + "' has non-integer type " +
                             ply_type_name(property.type));
      }
      header_.index_property = p;
      found = true;
    }
    if (!found) fail(faces.line, "face element has no 'vertex_indices' list property");
  }

  ByteSource& source_;
  PlyHeader header_;
  uint64_t line_ = 0;
  std::string line_text_;
};

}  // namespace

size_t size_of(PlyType type) {
  switch (type) {
    case PlyType::int8: case PlyType::uint8: return 1;
    case PlyType::int16: case PlyType::uint16: return 2;
    case PlyType::int32: case PlyType::uint32: case PlyType::float32: return 4;
    case PlyType::float64: return 8;
  }
  return 0;
}

bool is_integer(PlyType type) { return type != PlyType::float32 && type != PlyType::float64; }

std::optional<PlyType> parse_ply_type(std::string_view name) {
  for (const auto& entry : type_names) {
    if (name == entry.name) return entry.type;
  }
  return std::nullopt;
}

const char* ply_type_name(PlyType type) {
  for (const auto& entry : type_names) {
    if (entry.type == type) return entry.name;
  }
  return "?";
}

size_t PlyElement::fixed_record_size() const {
  size_t size = 0;
  for (const auto& property : properties) {
    if (property.is_list) return 0;
    size += size_of(property.type);
  }
  return size;
}

PlyHeader read_ply_header(ByteSource& source) { return HeaderParser(source).parse(); }

}  // namespace qemflow::io
