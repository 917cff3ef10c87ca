// ROS 2's sqlite3 storage (rosbag2_storage_default_plugins, the default before Iron): one .db3
// file with a `topics` table (id, name, type, serialization_format) and a `messages` table
// (topic_id, timestamp, data). Read with SQLite itself, read-only, one row at a time in timestamp
// order. A file SQLite finds corrupt part-way stops there: the rows before are delivered and
// damage() says where it stopped.
#include <sqlite3.h>

#include <filesystem>
#include <map>

#include "bag/bag_readers.hpp"

namespace terrastride::perception::bag {
namespace {

class Statement {
 public:
  Statement(sqlite3* db, const std::string& sql, const std::string& path) {
    if (sqlite3_prepare_v2(db, sql.c_str(), -1, &stmt_, nullptr) != SQLITE_OK)
      throw InputError(path + ": not a ROS 2 sqlite3 bag: " + sqlite3_errmsg(db));
  }
  ~Statement() { sqlite3_finalize(stmt_); }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;
  sqlite3_stmt* get() const { return stmt_; }

 private:
  sqlite3_stmt* stmt_ = nullptr;
};

std::string column_text(sqlite3_stmt* s, int i) {
  const unsigned char* t = sqlite3_column_text(s, i);
  return t ? reinterpret_cast<const char*>(t) : "";
}

// The path part of an SQLite "file:" URI: '?' would start the query, '#' a fragment and '%' an
// escape, so those (and every byte outside printable ASCII) are percent-encoded; a folder or file
// named "run?1" or "50%" then opens as itself instead of a truncated or mangled path.
std::string sqlite_uri_path(const std::string& path) {
  static const char kHex[] = "0123456789ABCDEF";
  std::string out;
  out.reserve(path.size());
  for (const char ch : path) {
    const auto c = static_cast<unsigned char>(ch);
    if (c == '?' || c == '#' || c == '%' || c <= 0x20 || c >= 0x7f) {
      out += '%';
      out += kHex[c >> 4];
      out += kHex[c & 15];
    } else {
      out += ch;
    }
  }
  return out;
}

class Db3Reader : public BagReader {
 public:
  explicit Db3Reader(const std::string& path) : BagReader(path) {
    std::error_code ec;
    damage_.file_bytes = std::filesystem::file_size(path, ec);
    // immutable=1: SQLite neither locks nor looks for a journal (a bag folder may be read-only).
    const std::string uri = "file:" + sqlite_uri_path(path) + "?mode=ro&immutable=1";
    if (sqlite3_open_v2(uri.c_str(), &db_, SQLITE_OPEN_READONLY | SQLITE_OPEN_URI, nullptr) !=
        SQLITE_OK) {
      const std::string msg = db_ ? sqlite3_errmsg(db_) : "out of memory";
      sqlite3_close(db_);
      throw InputError(path + ": cannot open as SQLite: " + msg);
    }
    try {
      Statement topics(db_, "SELECT id, name, type, serialization_format FROM topics", path);
      int rc;
      while ((rc = sqlite3_step(topics.get())) == SQLITE_ROW) {
        BagTopic t;
        t.name = column_text(topics.get(), 1);
        t.type = normalise_type(column_text(topics.get(), 2));
        t.encoding_name = column_text(topics.get(), 3);
        t.encoding = t.encoding_name == "cdr" ? MessageEncoding::kCdr : MessageEncoding::kOther;
        topics_[sqlite3_column_int64(topics.get(), 0)] = std::move(t);
      }
      if (rc != SQLITE_DONE)
        throw InputError(path + ": cannot read the topics table: " + sqlite3_errmsg(db_));
    } catch (...) {
      sqlite3_close(db_);
      throw;
    }
  }
  ~Db3Reader() override { sqlite3_close(db_); }

  std::string format() const override { return "sqlite3"; }
  std::vector<BagTopic> topics() const override {
    std::vector<BagTopic> out;
    for (const auto& [id, t] : topics_) out.push_back(t);
    return out;
  }

  void read(const std::function<bool(const BagTopic&)>& want,
            const std::function<void(const BagMessage&)>& on) override {
    std::string ids;
    for (const auto& [id, t] : topics_)
      if (!want || want(t)) ids += (ids.empty() ? "" : ",") + std::to_string(id);
    if (ids.empty()) return;
    Statement rows(db_,
                   "SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN (" + ids +
                       ") ORDER BY timestamp, id",
                   path_);
    int rc;
    size_t delivered = 0;
    while ((rc = sqlite3_step(rows.get())) == SQLITE_ROW) {
      auto t = topics_.find(sqlite3_column_int64(rows.get(), 0));
      if (t == topics_.end())
        throw InputError(path_ + ": a message of topic id " +
                         std::to_string(sqlite3_column_int64(rows.get(), 0)) +
                         " that the topics table does not list");
      BagMessage m;
      m.topic = &t->second;
      m.log_time_ns = sqlite3_column_int64(rows.get(), 1);
      const void* blob = sqlite3_column_blob(rows.get(), 2);
      const int n = sqlite3_column_bytes(rows.get(), 2);
      m.data = std::string_view(static_cast<const char*>(blob), blob ? static_cast<size_t>(n) : 0);
      on(m);
      ++delivered;
    }
    if (rc != SQLITE_DONE) {
      if (delivered == 0 && rc != SQLITE_CORRUPT)
        throw InputError(path_ + ": cannot read the messages: " + sqlite3_errmsg(db_));
      damage_.problems.push_back("SQLite stopped after " + std::to_string(delivered) +
                                 " messages: " + sqlite3_errmsg(db_) +
                                 " (the rest of the file skipped)");
    }
  }

 private:
  sqlite3* db_ = nullptr;
  std::map<int64_t, BagTopic> topics_;
};

}  // namespace

std::unique_ptr<BagReader> open_db3(const std::string& path) {
  return std::make_unique<Db3Reader>(path);
}

}  // namespace terrastride::perception::bag
