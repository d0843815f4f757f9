// `qemflow gen OUT --faces N [--shape NAME] [--seed S] [--shuffle S] [--quiet]`: writes a
// synthetic scan-like closed mesh (gen/generator.hpp) in the format OUT's extension
// names; with --shuffle, its vertices and faces in a random order (made in memory).
#include <chrono>
#include <filesystem>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>

#include "apps/qemflow/commands.hpp"
#include "gen/generator.hpp"
#include "io/indexed_mesh.hpp"

namespace qemflow::cli {
namespace {

struct GenArgs {
  std::string output;
  std::string faces;
  std::string shape = "blob";
  uint64_t seed = 1;
  std::optional<uint64_t> shuffle;
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
  cmd->add_option("--shuffle", args->shuffle,
                  "write the vertices and the faces each in a random order drawn from this seed (the "
                  "same surface; an input without locality); makes the mesh in memory, ~100 B per face");
  cmd->add_flag("--quiet", args->quiet, "no summary line on stderr");
  cmd->callback([&run, args] {
    run = [args] {
      const gen::GenOptions options{args->shape, gen::parse_face_count(args->faces), args->seed};
      gen::GenStats stats;
      if (args->shuffle) {
        const auto start = std::chrono::steady_clock::now();
        io::IndexedMesh mesh = gen::generate_in_memory(options);
        gen::shuffle(mesh, *args->shuffle);
        io::write_mesh(args->output, mesh);
        stats.vertex_count = mesh.vertices.size();
        stats.face_count = mesh.triangles.size();
        stats.bytes_written = std::filesystem::file_size(args->output);
        stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      } else {
        stats = gen::generate_to_file(options, args->output);
      }
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
