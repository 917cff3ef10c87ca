#include "common/solver_heap.hpp"

#include <malloc.h>

namespace terrastride::service {

void serve_solver_workspace_from_heap() {
  // A fixed threshold also turns off glibc's dynamic one; the trim threshold stays glibc's, so the
  // heap's top is still returned as it frees. glibc 2.36 accepts thresholds above 32 MiB.
  mallopt(M_MMAP_THRESHOLD, 512 << 20);
}

void return_free_heap_pages() { malloc_trim(0); }

}  // namespace terrastride::service
