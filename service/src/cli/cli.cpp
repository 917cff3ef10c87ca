#include "terrastride/service/cli.hpp"

#include <cmath>
#include <iostream>
#include <sstream>

namespace terrastride::service {

// One declaration per service/src/cli/cmd_NAME.cpp (see service/CMakeLists.txt).
#define TERRASTRIDE_COMMAND(name) void add_##name##_command(CLI::App& app);
#include "terrastride_commands.inc"
#undef TERRASTRIDE_COMMAND

Eigen::VectorXd parse_numbers(const std::string& text, int n, const std::string& what) {
  std::vector<double> values;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    size_t used = 0;
    double v = 0;
    try {
      v = std::stod(item, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    // Reject trailing junk ("1.0m"), empty items and non-finite values.
    while (used < item.size() && std::isspace(static_cast<unsigned char>(item[used]))) ++used;
    if (item.empty() || used != item.size() || !std::isfinite(v))
      throw CommandError(what + ": '" + text + "' is not a list of " + std::to_string(n) +
                         " finite numbers separated by commas");
    values.push_back(v);
  }
  if (static_cast<int>(values.size()) != n)
    throw CommandError(what + ": expected " + std::to_string(n) + " numbers, got '" + text + "'");
  return Eigen::Map<Eigen::VectorXd>(values.data(), n);
}

int run_cli(int argc, char** argv) {
  CLI::App app{
      "terrastride: hardware-feasible motion planning for legged robots over terrain seen as "
      "point clouds (Bratta et al., ICRA 2020, and beyond)."};
  app.name("terrastride");
  app.require_subcommand(1, 1);
  app.set_version_flag("--version", "terrastride 0.1.0");
#define TERRASTRIDE_COMMAND(name) add_##name##_command(app);
#include "terrastride_commands.inc"
#undef TERRASTRIDE_COMMAND
  return run_command_line(app, argc, argv);
}

int run_command_line(CLI::App& app, int argc, char** argv) {
  // "terrastride robot fk": the chain of subcommands that ran, for error messages.
  auto command_name = [&app] {
    std::string name = app.get_name();
    for (const CLI::App* level = &app;;) {
      const auto subs = level->get_subcommands();
      if (subs.empty()) return name;
      level = subs.front();
      name += " " + level->get_name();
    }
  };
  try {
    app.parse(argc, argv);
    return 0;
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // Usage errors: name the problem, point at --help, exit 2. CLI11 reports a missing required
    // option before an unknown one, so unknown arguments are named first when there are any.
    std::string unexpected;
    for (const std::string& extra : app.remaining(true)) unexpected += " '" + extra + "'";
    if (!unexpected.empty())
      std::cerr << app.get_name() << ": error: unknown subcommand or option:" << unexpected << "\n";
    else
      std::cerr << app.get_name() << ": error: " << e.what() << "\n";
    std::cerr << "Run '" << app.get_name() << " --help' for usage.\n";
    return 2;
  } catch (const CommandError& e) {
    std::cerr << command_name() << ": error: " << e.what() << "\n";
    return e.exit_code();
  } catch (const std::exception& e) {
    std::cerr << command_name() << ": error: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace terrastride::service
