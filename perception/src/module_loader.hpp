// Loading a module of our own on first use (dlopen): the PCL module (pcl_module.hpp) and the
// ROS 1 bag module (bag/ros1_module.hpp) keep heavy libraries out of processes that never need
// them. Both are looked for the same way, in order: $ENV_VARIABLE; FILE beside the running
// executable (build/ and an installed tree); the build tree's path compiled into the caller (the
// test executables in build/tests/...).
#pragma once

#include <string>

namespace terrastride::perception::detail {

struct ModuleSpec {
  const char* file;          // e.g. "terrastride_pcl.so"
  const char* entry_symbol;  // extern "C" function returning the module's function table
  const char* env_variable;  // overrides where the module is looked for
  const char* build_path;    // the build tree's path, or nullptr
  const char* what;          // e.g. "the PCL module (PCD/PLY reading and cloud filters)"
};

// dlopens the first candidate whose entry function returns a table accepted by
// `accept(table)` (its version matches the caller's build) and returns that table; the module is
// never unloaded. Throws InputError naming the module, the variable to set and every path tried
// with why it failed. Not synchronised: callers call it once (std::call_once).
const void* load_module(const ModuleSpec& spec, bool (*accept)(const void* table));

// Typed: the entry function returns a `const Module*` whose int `version` must equal `kVersion`
// (the module and its loader come from the same build).
template <class Module, int kVersion>
const Module& load_module(const ModuleSpec& spec) {
  return *static_cast<const Module*>(load_module(spec, [](const void* table) {
    return static_cast<const Module*>(table)->version == kVersion;
  }));
}

}  // namespace terrastride::perception::detail
