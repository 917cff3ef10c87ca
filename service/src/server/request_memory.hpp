// The memory requests hold while they arrive and wait: the server-wide budget of buffered request
// bytes (ServerOptions::max_buffered_bytes), a hold on part of it, and the buffer a large frame is
// received into.
#pragma once

#include <sys/mman.h>

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <utility>

namespace terrastride::service {

// The server-wide count of buffered request bytes. Shared with jobs, which give their bytes back
// on worker threads, possibly after the server is gone.
struct ByteBudget {
  explicit ByteBudget(std::size_t l) : limit(l) {}
  const std::size_t limit;
  std::atomic<std::size_t> used{0};
  std::atomic<std::uint64_t> refused{0};
  bool fits(std::size_t more) const { return used.load() + more <= limit; }
};

// Bytes counted against a ByteBudget until released (or destroyed).
class BudgetHold {
 public:
  BudgetHold() = default;
  BudgetHold(BudgetHold&& o) noexcept { *this = std::move(o); }
  BudgetHold& operator=(BudgetHold&& o) noexcept {
    if (this != &o) {
      release();
      budget_ = std::move(o.budget_);
      bytes_ = o.bytes_;
      o.bytes_ = 0;
    }
    return *this;
  }
  ~BudgetHold() { release(); }
  void add(const std::shared_ptr<ByteBudget>& budget, std::size_t n) {
    budget_ = budget;
    bytes_ += n;
    budget_->used += n;
  }
  void release() {
    if (budget_ && bytes_ > 0) budget_->used -= bytes_;
    bytes_ = 0;
  }

 private:
  std::shared_ptr<ByteBudget> budget_;
  std::size_t bytes_ = 0;
};

// A frame too large for a connection's fixed buffer, received into its own anonymous mapping:
// pages are committed only as bytes arrive, and munmap returns them to the system at once (a
// malloc'ed block of this size could stay in the heap after it is freed).
class FrameBuffer {
 public:
  FrameBuffer() = default;
  FrameBuffer(FrameBuffer&& o) noexcept { *this = std::move(o); }
  FrameBuffer& operator=(FrameBuffer&& o) noexcept {
    if (this != &o) {
      reset();
      std::swap(data_, o.data_);
      std::swap(size_, o.size_);
    }
    return *this;
  }
  ~FrameBuffer() { reset(); }
  bool allocate(std::size_t n) {
    reset();
    void* p = ::mmap(nullptr, n, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) return false;
    data_ = static_cast<char*>(p);
    size_ = n;
    return true;
  }
  void reset() {
    if (data_) ::munmap(data_, size_);
    data_ = nullptr;
    size_ = 0;
  }
  char* data() const { return data_; }
  std::size_t size() const { return size_; }

 private:
  char* data_ = nullptr;
  std::size_t size_ = 0;
};

}  // namespace terrastride::service
