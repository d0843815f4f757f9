#include "config/config_file.hpp"

#include <filesystem>
#include <functional>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <toml++/toml.h>

namespace qemflow::config {
namespace {

// CLI11 reads a config file for the root app only (2.1 does not process a subcommand's),
// so --config is the root's, given after the command by fallthrough, and its keys are
// checked against and applied to the command being run. CLI11 hands the formatter a
// stream, not the path; the path is the --config option's value, parsed by then.
class TomlConfig : public CLI::Config {
 public:
  explicit TomlConfig(const CLI::App* root) : root_(root) {}
  void set_option(const CLI::Option* option) { option_ = option; }

  std::string to_config(const CLI::App*, bool, bool, std::string) const override { return {}; }

  std::vector<CLI::ConfigItem> from_config(std::istream& input) const override {
    const std::string path = option_ && option_->count() == 1 ? option_->results().front() : "--config";
    toml::table table;
    try {
      table = toml::parse(input, path);
    } catch (const toml::parse_error& e) {
      fail(path, e.source().begin, std::string(e.description()));
    }
    const std::vector<const CLI::App*> commands =
        root_->get_subcommands(std::function<bool(const CLI::App*)>([](const CLI::App* c) { return c->parsed(); }));
    if (commands.empty()) fail(path, {1, 1}, "--config needs a command (qemflow simplify IN OUT --config FILE)");
    const CLI::App* command_ = commands.front();
    std::vector<CLI::ConfigItem> items;
    for (const auto& [key_view, node] : table) {
      std::string key(key_view.str());
      for (char& c : key)
        if (c == '_') c = '-';
      const toml::source_position at = key_view.source().begin;
      if (node.is_table())
        fail(path, at, "[" + std::string(key_view.str()) + "] is a table; the file holds qemflow " + command_->get_name() +
                           "'s flags at its top level");
      const CLI::Option* option = command_->get_option_no_throw("--" + key);
      if (!option || !option->get_configurable())
        fail(path, at, "'" + std::string(key_view.str()) + "' is not a flag of qemflow " + command_->get_name());
      // The command line wins: a file value is dropped when it is given there, or when
      // it excludes a flag given there (the file's ratio beside --target-faces).
      bool overridden = option->count() > 0;
      for (const CLI::Option* excluded : option->get_excludes()) overridden = overridden || excluded->count() > 0;
      if (overridden) continue;
      std::string value;
      // value<T>() converts between kinds (an integer reads as a bool), so test the kind.
      if (node.is_string())
        value = *node.value<std::string>();
      else if (node.is_boolean())
        value = *node.value<bool>() ? "true" : "false";
      else if (node.is_integer())
        value = std::to_string(*node.value<int64_t>());
      else if (node.is_floating_point()) {
        std::ostringstream text;
        text.precision(17);
        text << *node.value<double>();
        value = text.str();
      } else
        fail(path, at, "'" + key + "' must be a string, a number or a boolean");
      items.push_back({{command_->get_name()}, key, {value}});
    }
    return items;
  }

 private:
  // A FileError, which CLI11 reports only after --help had its turn.
  [[noreturn]] static void fail(const std::string& path, const toml::source_position& at, const std::string& problem) {
    throw CLI::FileError(path + ": line " + std::to_string(at.line) + ", column " + std::to_string(at.column) + ": " +
                           problem);
  }

  const CLI::App* root_;
  const CLI::Option* option_ = nullptr;
};

}  // namespace

void add_config_option(CLI::App& root) {
  auto formatter = std::make_shared<TomlConfig>(&root);
  CLI::Option* option = root.set_config("--config", "", "read the command's flag values from a TOML file (flags on the command line win)");
  option->expected(1);
  formatter->set_option(option);
  root.config_formatter(formatter);
  // Settings reach commands at their creation; these exist already.
  for (CLI::App* command : root.get_subcommands(std::function<bool(CLI::App*)>([](CLI::App*) { return true; }))) {
    command->fallthrough();
    command->footer("--config FILE: read this command's flag values from a TOML file (key = the flag without --; "
                    "flags on the command line win)");
  }
}

std::string file_error_message(const CLI::App& root, const CLI::FileError& error) {
  const CLI::Option* option = root.get_option_no_throw("--config");
  if (!option || option->count() != 1) return error.what();
  const std::string& path = option->results().front();
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) return path + ": is a directory, not a TOML file";
  if (!std::filesystem::exists(path, ec)) return path + ": no such file";
  return error.what();
}

}  // namespace qemflow::config
