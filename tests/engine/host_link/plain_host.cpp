// A host program that uses the qemflow engine and nothing else of note; built with
// AddressSanitizer (as a host's or qemflow's own CI does) it must run clean: new and
// delete have to come from the same allocator family.
#include <memory>
#include <string>

#include "engine/process_memory.hpp"

int main() {
  auto text = std::make_unique<std::string>(100, 'x');
  return qemflow::engine::resident_bytes() > 0 && text->size() == 100 ? 0 : 1;
}
