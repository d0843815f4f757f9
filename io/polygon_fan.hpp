#pragma once
// A polygon being fan-triangulated while its indices are read, so that its triangles
// can leave in bounded batches and neither its index list nor all its triangles are
// ever held: a polygon of millions of vertices costs two indices of state. Internal to
// io/ (the PLY and OBJ readers and the bulk decoder).
#include <cstdint>

namespace qemflow::io {

struct PolygonFan {
  uint64_t first = 0;  // the fan's apex: the polygon's first index
  uint64_t prev = 0;   // the index read last
  uint64_t seen = 0;   // indices read so far
  // Adds the next index; calls emit(a, b, c) for the triangle it completes, if any.
  // The triangles are (i0, i_k, i_k+1) for k = 1.., the order the readers always used.
  template <class Emit>
  void add(uint64_t index, Emit&& emit) {
    if (seen == 0) first = index;
    else if (seen >= 2) emit(first, prev, index);
    prev = index;
    ++seen;
  }
  void reset() { seen = 0; }
};

}  // namespace qemflow::io
