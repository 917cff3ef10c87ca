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

}  // namespace terrastride::service
