// The scenario runners' BLAS kernel, pinned. OpenBLAS (the product's BLAS, service/CMakeLists.txt)
// picks its kernels by the CPU it starts on, and MUMPS's dense blocks then round differently on
// different machines: Ipopt's iterates move, and with them which closed-loop steps converge within
// their iteration budget (measured on one AVX-512 machine: the undisturbed pallet_15 closed loop
// has 33 own solutions of 108 with the SkylakeX kernel OpenBLAS picks there, 31 with Haswell's or
// Zen's). Figures counted in iterations repeat run to run on one machine; pinned, they also
// repeat across x86-64 machines with AVX2. OpenBLAS reads OPENBLAS_CORETYPE when it is loaded,
// before main, so a runner started without it sets it and executes itself again.
#pragma once

#include <dlfcn.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <string>

namespace terrastride::bench {

inline constexpr const char* kPinnedBlasKernel = "Haswell";

// Starts this process again with OPENBLAS_CORETYPE=Haswell unless it is set (a caller's choice
// stands) or the CPU lacks AVX2 (the kernel would not run there); returns when nothing is to be
// done or the exec failed (the run then goes on with OpenBLAS's own choice, which
// blas_kernel_name reports).
inline void pin_blas_kernel(char** argv) {
  if (std::getenv("OPENBLAS_CORETYPE") != nullptr) return;
  std::ifstream cpuinfo("/proc/cpuinfo");
  std::string line;
  bool avx2 = false;
  while (!avx2 && std::getline(cpuinfo, line))
    avx2 = line.rfind("flags", 0) == 0 && line.find(" avx2") != std::string::npos;
  if (!avx2) return;
  ::setenv("OPENBLAS_CORETYPE", kPinnedBlasKernel, 1);
  ::execv("/proc/self/exe", argv);
}

// The kernel OpenBLAS runs on ("unknown" when the BLAS is not OpenBLAS), for a runner's header.
inline std::string blas_kernel_name() {
  using CoreName = char* (*)();
  const auto name = reinterpret_cast<CoreName>(::dlsym(RTLD_DEFAULT, "openblas_get_corename"));
  return name != nullptr ? std::string(name()) : std::string("unknown");
}

}  // namespace terrastride::bench
