# Per-target build settings that cut compile time where run-time speed does not matter.
#
# terrastride_light_optimisation(TARGET LEVEL): compile TARGET at LEVEL (-Og, -O1, -O2) instead of
# the build type's -O3 in optimised builds (Release, RelWithDebInfo, MinSizeRel; Debug stays -O0).
# For test executables and command-line glue: GCC spends most of a Release build in -O3's inlining
# and vectorisation of template-heavy code (Eigen, nlohmann::json, GoogleTest), which such code
# does not need. Results do not change: without -ffast-math no level reassociates floating-point
# arithmetic. The planning's hot path (planner/, terrain/) keeps -O3; perception/, collision/ and
# simulation/ compile at -O2, the service (command line, report, export, server) at -O1, the
# tests at -Og.
# Target options come after CMAKE_CXX_FLAGS_<CONFIG> on the command line, so LEVEL wins.
# The sanitizer build (TERRASTRIDE_SANITIZE) compiles everything at -O1 already and keeps it.
function(terrastride_light_optimisation target level)
  if(TERRASTRIDE_SANITIZE)
    return()
  endif()
  target_compile_options(${target} PRIVATE $<$<CONFIG:Release,RelWithDebInfo,MinSizeRel>:${level}>)
endfunction()

# terrastride_precompile_headers(TARGET HEADER...): precompile the heavy third-party headers most
# of TARGET's translation units include (Eigen, nlohmann::json, OctoMap, PCL, CLI11, GoogleTest).
# GCC parses each of them in 1-2 s of CPU per translation unit; from the precompiled header it
# loads them in a fraction of that. The header is force-included before each source; it changes
# no code GCC generates (the same declarations, seen earlier), so products are bit-identical.
# Off by default: measured on a clean Release build of the binary (2 cores, CCACHE_DISABLE=1) it
# took 21.0 CPU-min with them against 20.2 without; GCC's -O3 optimisation and template
# instantiation, not parsing, are most of these translation units' time, and building and loading
# the precompiled headers ate the parse time saved.
option(TERRASTRIDE_PCH "Precompile heavy third-party headers per library and for the tests" OFF)
function(terrastride_precompile_headers target)
  if(TERRASTRIDE_PCH)
    target_precompile_headers(${target} PRIVATE ${ARGN})
  endif()
endfunction()

# terrastride_unity_build(TARGET [EXCLUDE FILE...]): compile TARGET's sources in unity batches of
# 8 (CMake's UNITY_BUILD): the heavy headers nearly every file includes (Eigen, nlohmann::json,
# OctoMap, CLI11, the modules' own) are parsed once per batch instead of once per file, about
# 3-5 s of CPU each. Eight keeps enough batches for -j2 and a rebuild after an edit short. Names in
# the anonymous namespaces of one target's files must therefore differ. EXCLUDE lists files
# compiled on their own (files under frequent change, whose names the batch would constrain).
function(terrastride_unity_build target)
  cmake_parse_arguments(U "" "" "EXCLUDE" ${ARGN})
  set_target_properties(${target} PROPERTIES UNITY_BUILD ON UNITY_BUILD_BATCH_SIZE 8)
  if(U_EXCLUDE)
    set_source_files_properties(${U_EXCLUDE} TARGET_DIRECTORY ${target} PROPERTIES
                                SKIP_UNITY_BUILD_INCLUSION ON)
  endif()
endfunction()
