// `qemflow gen OUT --faces N [--shape NAME] [--seed S] [--quiet]`: writes a synthetic
// scan-like closed mesh (gen/generator.hpp) in the format OUT's extension names.
#include <cstdio>
#include <memory>
#include <string>

#include "apps/qemflow/commands.hpp"
#include "gen/generator.hpp"

namespace qemflow::cli {
namespace {

struct GenArgs {
  std::string output;
  std::string faces;
  std::string shape = "blob";
  uint64_t seed = 1;
  bool quiet = false;
};

std::string shape_help() {
  std::string list;
  for (const auto& name : gen::shape_names()) list += (list.empty() ? "" : "|") + name;
  return "surface to make: " + list + " (blob: lumpy rock, sphere-like; terrain: closed slab with a "
         "mountain heightfield; figure: lumpy bent ring, genus 1)";
}

}  // namespace

void add_gen_command(CLI::App& root, Run& run) {
  auto args = std::make_shared<GenArgs>();
  auto* cmd = root.add_subcommand("gen", "write a synthetic scan-like closed manifold mesh");
  cmd->add_option("OUT", args->output, "output mesh: .ply (binary), .obj, optionally .zst")->required();
  cmd->add_option("--faces", args->faces,
                  "triangle count: 300000, 2M, 1.5M, 1G (K/M/G = 1e3/1e6/1e9); odd counts round up by one")
      ->required();
  cmd->add_option("--shape", args->shape, shape_help())->capture_default_str();
  cmd->add_option("--seed", args->seed, "noise seed; the output is a pure function of shape, faces, seed")
      ->capture_default_str();
  cmd->add_flag("--quiet", args->quiet, "no summary line on stderr");
  cmd->callback([&run, args] {
    run = [args] {
      const gen::GenOptions options{args->shape, gen::parse_face_count(args->faces), args->seed};
      const gen::GenStats stats = gen::generate_to_file(options, args->output);
      if (!args->quiet) {
        std::fprintf(stderr,
                     "gen: %s, %llu vertices, %llu faces, %.2f s, %.3gM faces/s, %.1f MB -> %s\n",
                     options.shape.c_str(), static_cast<unsigned long long>(stats.vertex_count),
                     static_cast<unsigned long long>(stats.face_count), stats.seconds,
                     static_cast<double>(stats.face_count) / stats.seconds / 1e6,
                     static_cast<double>(stats.bytes_written) / 1e6, args->output.c_str());
      }
    };
  });
}

}  // namespace qemflow::cli
