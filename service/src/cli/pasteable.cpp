#include "pasteable.hpp"

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <sstream>

namespace terrastride::service {

namespace fs = std::filesystem;

std::string shell_word(const std::string& s) {
  const bool plain = !s.empty() && s.find_first_not_of(
                                       "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz"
                                       "0123456789_-+=./,:@%") == std::string::npos;
  if (plain) return s;
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

std::string pasteable_program() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (ec || self.empty()) return "terrastride";
  const char* path_env = std::getenv("PATH");
  std::stringstream dirs(path_env ? path_env : "");
  std::string dir;
  // The first "terrastride" on PATH is what a bare name runs.
  while (std::getline(dirs, dir, ':')) {
    const fs::path candidate = fs::path(dir.empty() ? "." : dir) / "terrastride";
    if (::access(candidate.c_str(), X_OK) != 0) continue;
    if (fs::equivalent(candidate, self, ec) && !ec) return "terrastride";
    break;
  }
  return shell_word(self.string());
}

std::string map_folder_for(const std::string& file) {
  return fs::path(file).stem().string() + "-map";
}

std::string map_command(const std::string& file) {
  return pasteable_program() + " map " + shell_word(file) + " --out " +
         shell_word(map_folder_for(file));
}

std::string map_it_first(const std::string& file) {
  return "a file is not a map: map it first with `" + map_command(file) +
         "` (add the pose flags `map` asks for, if any) and pass --terrain " +
         shell_word(map_folder_for(file)) + ", or give an OctoMap (.bt, .ot) or a scene name";
}

}  // namespace terrastride::service
