#pragma once
// Giving a vector's storage back before the vector goes out of scope: the governor's
// lease for an array is returned right after it, so the memory must go with it.
#include <vector>

namespace qemflow {

// Frees a vector's storage. `v = {}` would keep the capacity (it assigns an empty
// initializer list): memory resident and no longer lent, as the loader's positions
// were through every epoch (24 B per input vertex).
template <class T, class Allocator>
void release_memory(std::vector<T, Allocator>& v) {
  std::vector<T, Allocator>().swap(v);
}

}  // namespace qemflow
