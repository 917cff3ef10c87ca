#include "worker_pool.hpp"

#include <algorithm>

namespace terrastride::service {

WorkerPool::WorkerPool(int workers, int capacity, std::function<void(std::shared_ptr<Job>)> run)
    : capacity_(static_cast<std::size_t>(std::max(0, capacity))), run_(std::move(run)) {
  for (int i = 0; i < std::max(1, workers); ++i) threads_.emplace_back([this] { loop(); });
}

bool WorkerPool::try_submit(std::shared_ptr<Job> job) {
  std::lock_guard<std::mutex> lock(mu_);
  if (stopping_) return false;
  if (queue_.size() + running_ >= threads_.size() + capacity_) return false;
  queue_.push_back(std::move(job));
  cv_.notify_one();
  return true;
}

bool WorkerPool::try_remove(const std::shared_ptr<Job>& job) {
  std::lock_guard<std::mutex> lock(mu_);
  for (auto it = queue_.begin(); it != queue_.end(); ++it)
    if (*it == job) {
      queue_.erase(it);
      return true;
    }
  return false;
}

std::vector<std::shared_ptr<Job>> WorkerPool::take_all_queued() {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<std::shared_ptr<Job>> out(queue_.begin(), queue_.end());
  queue_.clear();
  return out;
}

std::size_t WorkerPool::queued() const {
  std::lock_guard<std::mutex> lock(mu_);
  return queue_.size();
}

std::size_t WorkerPool::running() const {
  std::lock_guard<std::mutex> lock(mu_);
  return running_;
}

void WorkerPool::stop() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (stopping_ && threads_.empty()) return;
    stopping_ = true;
    queue_.clear();
  }
  cv_.notify_all();
  for (auto& t : threads_)
    if (t.joinable()) t.join();
  threads_.clear();
}

void WorkerPool::loop() {
  for (;;) {
    std::shared_ptr<Job> job;
    {
      std::unique_lock<std::mutex> lock(mu_);
      cv_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      job = std::move(queue_.front());
      queue_.pop_front();
      ++running_;
    }
    run_(job);  // calls finished() before it hands the reply over
  }
}

void WorkerPool::finished() {
  std::lock_guard<std::mutex> lock(mu_);
  --running_;
}

}  // namespace terrastride::service
