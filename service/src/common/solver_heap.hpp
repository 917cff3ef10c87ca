// Heap policy of the commands that run one cold solve in a short-lived process (`plan`, `demo`).
//
// MUMPS allocates its factorisation workspace anew for every factorisation and frees it after
// (Ipopt's default mumps_mem_percent reserves ~11x MUMPS's estimate: pallet_15 `all` asks for
// 56-92 MB, of which it touches ~20 MB). glibc serves blocks above its largest dynamic mmap
// threshold (32 MiB) with a fresh mmap and unmaps them on free, so every factorisation faults in
// and zeroes again the pages it touches: ~48,000 page faults and ~0.14 s of system CPU in a
// pallet_15 `all` plan (docs/design.md §12.6). Served from the heap, the freed workspace is reused
// by the next factorisation. The long-lived server keeps glibc's default: its session steps'
// workspaces are below the threshold already, and it must not hold freed memory per thread.
#pragma once

namespace terrastride::service {

// Serves allocations up to 512 MiB from the heap rather than from their own mmap. Call once,
// before the solve, in a process that solves once.
void serve_solver_workspace_from_heap();

// Returns the heap's free pages to the system (malloc_trim): called once the solve is done, so
// that what the solve freed does not add to the peak resident memory of what follows (the
// post-hoc checks' and the plan file's threads allocate from their own arenas).
void return_free_heap_pages();

}  // namespace terrastride::service
