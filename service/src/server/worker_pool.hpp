// The bounded worker pool that runs the server's long operations (OpKind::kWorker): a fixed set
// of threads serving a FIFO of at most `capacity` waiting jobs.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

namespace terrastride::service {

struct Job;  // connection.hpp

class WorkerPool {
 public:
  WorkerPool(int workers, int capacity, std::function<void(std::shared_ptr<Job>)> run);
  ~WorkerPool() { stop(); }

  // False when every worker is taken and `capacity` jobs already wait (the caller replies
  // `busy`).
  bool try_submit(std::shared_ptr<Job> job);
  // Removes a job that has not started; false when it is running or done.
  bool try_remove(const std::shared_ptr<Job>& job);
  std::vector<std::shared_ptr<Job>> take_all_queued();
  std::size_t queued() const;
  // The job of the calling worker is done: its place is free. Called by `run` before it hands
  // the reply to the I/O thread, so a client that has the reply finds the place free (counted
  // after the hand-over, a request sent at once could be refused `busy`).
  void finished();
  std::size_t running() const;
  std::size_t workers() const { return threads_.size(); }
  std::size_t capacity() const { return capacity_; }
  // Drops the queued jobs and joins the threads once their running jobs end.
  void stop();

 private:
  void loop();

  std::size_t capacity_;
  std::function<void(std::shared_ptr<Job>)> run_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::shared_ptr<Job>> queue_;
  std::size_t running_ = 0;
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

}  // namespace terrastride::service
