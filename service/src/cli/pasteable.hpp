// Commands terrastride prints for the user to paste (`regions`' plan commands, `plan`'s next
// steps): words quoted for the shell and the binary named so the shell finds it.
#pragma once

#include <string>

namespace terrastride::service {

// `s` as one shell word: unchanged when it holds only characters no shell treats specially,
// else single-quoted.
std::string shell_word(const std::string& s);

// How a pasted command names this binary: "terrastride" when that name on PATH is this very
// executable, else its absolute path (a build tree's `build/terrastride` is rarely on PATH, and a
// bare name would then run nothing, or another build).
std::string pasteable_program();

// For a file given where a map is expected (a point cloud): the `map` command to paste, which
// writes the folder map_folder_for(file) (the file's name with "-map").
std::string map_folder_for(const std::string& file);
std::string map_command(const std::string& file);

// The error hint of plan, regions and check for such a file: map it first, then pass the folder.
std::string map_it_first(const std::string& file);

}  // namespace terrastride::service
