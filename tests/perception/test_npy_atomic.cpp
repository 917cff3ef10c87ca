// NPY writer/reader round trips and the atomic output helpers: all-or-nothing writes that never
// replace what the tool did not write (foreign folders, devices, pipes, links) and clean up after
// killed runs.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <fstream>
#include <sstream>
#include <thread>
#include <vector>

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/npy.hpp"
#include "test_util.hpp"

namespace terrastride::perception {
namespace {

using test::expect_input_error;
using test::ScratchDir;

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

size_t entries(const std::filesystem::path& dir) {
  return static_cast<size_t>(std::distance(std::filesystem::directory_iterator(dir), {}));
}

namespace fs = std::filesystem;

// A kind without legacy names: only empty folders and marked outputs are replaced.
const OutputDirKind kTestKind{"test", {}, {}, {}};

// The map's kind as cmd_map.cpp declares it (older outputs recognised by their names).
const OutputDirKind kMapLikeKind{"map",
                                 {"terrain.json", "octomap.bt", "layers/"},
                                 {"terrain.json", "octomap.bt", "layers/", "layers/*.npy"},
                                 {}};

mode_t file_type(const std::string& path) {
  struct stat st;
  return ::lstat(path.c_str(), &st) == 0 ? (st.st_mode & S_IFMT) : 0;
}

// A pid that no longer runs: a child that exited and was reaped.
pid_t dead_pid() {
  const pid_t child = ::fork();
  if (child == 0) ::_exit(0);
  int status = 0;
  ::waitpid(child, &status, 0);
  return child;
}

// A device node in the scratch directory with the numbers of a real one (1,3 = null, 1,7 = full),
// so that even a broken writer that renames over it only replaces a node in the scratch folder.
// Root only; empty when the node cannot be made (e.g. no CAP_MKNOD in a container).
std::string scratch_device(const ScratchDir& dir, const std::string& name, unsigned minor) {
  const std::string path = dir.file(name);
  if (::geteuid() != 0 || ::mknod(path.c_str(), S_IFCHR | 0666, makedev(1, minor)) != 0) return "";
  return path;
}

TEST(Npy, RoundTripAllDtypes) {
  ScratchDir dir;
  const std::vector<float> f = {1.5f, -2.0f, 3.0f, 4.0f, 5.0f, 6.25f};
  const std::vector<double> d = {1e-300, 2.0, -3.5, 4.0};
  const std::vector<uint8_t> u = {0, 1, 255, 7, 8, 9, 10, 11, 12};
  write_npy(dir.file("f.npy"), f.data(), 2, 3);
  write_npy(dir.file("d.npy"), d.data(), 4, 1);
  write_npy(dir.file("u.npy"), u.data(), 3, 3);

  NpyArray a = read_npy(dir.file("f.npy"));
  EXPECT_EQ(a.dtype, "<f4");
  EXPECT_EQ(a.shape, (std::vector<size_t>{2, 3}));
  EXPECT_EQ(a.at(1, 2), 6.25);
  EXPECT_EQ(a.at(0, 1), -2.0);
  a = read_npy(dir.file("d.npy"));
  EXPECT_EQ(a.dtype, "<f8");
  EXPECT_EQ(a.rows(), 4u);
  EXPECT_EQ(a.cols(), 1u);
  EXPECT_EQ(a.at(0, 0), 1e-300);
  a = read_npy(dir.file("u.npy"));
  EXPECT_EQ(a.dtype, "|u1");
  EXPECT_EQ(a.at(0, 2), 255.0);
  EXPECT_EQ(a.at(2, 2), 12.0);
}

TEST(Npy, HeaderIsAlignedAndNumpyReadable) {
  ScratchDir dir;
  const std::vector<float> f(12, 0.0f);
  write_npy(dir.file("f.npy"), f.data(), 4, 3);
  const std::string bytes = slurp(dir.file("f.npy"));
  ASSERT_GE(bytes.size(), 10u);
  EXPECT_EQ(bytes.substr(0, 6), "\x93NUMPY");
  const size_t header_len = static_cast<unsigned char>(bytes[8]) |
                            (static_cast<size_t>(static_cast<unsigned char>(bytes[9])) << 8);
  // numpy requires the data to start on a 64-byte boundary and the header to end with '\n'.
  EXPECT_EQ((10 + header_len) % 64, 0u);
  EXPECT_EQ(bytes[10 + header_len - 1], '\n');
  EXPECT_NE(bytes.find("'shape': (4, 3)"), std::string::npos);
  EXPECT_EQ(bytes.size(), 10 + header_len + 48);
}

TEST(Npy, ReadsVersion2Header) {
  ScratchDir dir;
  std::string header = "{'descr': '<f8', 'fortran_order': False, 'shape': (1, 2), }";
  while ((12 + header.size() + 1) % 64) header += ' ';
  header += '\n';
  std::string bytes("\x93NUMPY\x02\x00", 8);
  for (int i = 0; i < 4; ++i) bytes += static_cast<char>((header.size() >> (8 * i)) & 0xff);
  bytes += header;
  const double v[2] = {3.0, -4.0};
  bytes.append(reinterpret_cast<const char*>(v), sizeof(v));
  test::write_text(dir.file("v2.npy"), bytes);
  const NpyArray a = read_npy(dir.file("v2.npy"));
  EXPECT_EQ(a.at(0, 1), -4.0);
}

TEST(Npy, ErrorsNameTheFile) {
  expect_input_error([] { read_npy("/no/such/layer.npy"); }, {"/no/such/layer.npy", "cannot open"});
  const float f[3] = {1, 2, 3};
  expect_input_error([&] { write_npy("/no/such/dir/layer.npy", f, 1, 3); },
                     {"/no/such/dir/layer.npy"});
}

TEST(AtomicFile, ReplacesExistingContentAndLeavesNoTemp) {
  ScratchDir dir;
  const std::string path = dir.file("a.txt");
  write_file_atomically(path, "first");
  write_file_atomically(path, "second, longer");
  EXPECT_EQ(slurp(path), "second, longer");
  EXPECT_EQ(entries(dir.path()), 1u);
}

TEST(AtomicFile, RefusesDirectoryTarget) {
  ScratchDir dir;
  std::filesystem::create_directory(dir.file("sub"));
  expect_input_error([&] { write_file_atomically(dir.file("sub"), "x"); }, {"sub", "directory"});
  EXPECT_EQ(entries(dir.path()), 1u);
}

TEST(AtomicDir, UncommittedLeavesNothing) {
  ScratchDir dir;
  const std::string out = dir.file("out");
  {
    AtomicOutputDir o(out, kTestKind);
    write_file_atomically(o.path() + "/terrain.json", "{}");
    EXPECT_FALSE(std::filesystem::exists(out));
    // Simulates an error part-way: the destructor runs without commit().
  }
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_EQ(entries(dir.path()), 0u);
}

TEST(AtomicDir, CommitCreatesAndReplaces) {
  ScratchDir dir;
  const std::string out = dir.file("nested/out");
  {
    AtomicOutputDir o(out, kTestKind);
    write_file_atomically(o.path() + "/a.txt", "old");
    std::filesystem::create_directory(o.path() + "/layers");
    o.commit();
    EXPECT_TRUE(o.committed());
  }
  EXPECT_EQ(slurp(out + "/a.txt"), "old");
  {
    AtomicOutputDir o(out + "/", kTestKind);  // a trailing slash means the same directory
    write_file_atomically(o.path() + "/b.txt", "new");
    EXPECT_EQ(slurp(out + "/a.txt"), "old");  // still the old output until commit
    o.commit();
  }
  EXPECT_FALSE(std::filesystem::exists(out + "/a.txt"));
  EXPECT_EQ(slurp(out + "/b.txt"), "new");
  EXPECT_EQ(entries(dir.path() / "nested"), 1u);  // no temp or backup directories left
}

TEST(AtomicDir, RefusesFileInTheWay) {
  ScratchDir dir;
  test::write_text(dir.file("f"), "x");
  expect_input_error([&] { AtomicOutputDir o(dir.file("f"), kTestKind); }, {"not a directory"});
}

TEST(AtomicDir, RefusesAForeignFolderAndLeavesItUntouched) {
  ScratchDir dir;
  const std::string out = dir.file("scans");
  fs::create_directories(out + "/sub");
  test::write_text(out + "/scan.pcd", "my only scan");
  test::write_text(out + "/sub/notes.txt", "notes");
  expect_input_error([&] { check_output_dir(out, kMapLikeKind); },
                     {out, "did not write", "choose an empty or new folder"});
  expect_input_error([&] { AtomicOutputDir o(out, kMapLikeKind); },
                     {out, "did not write", "choose an empty or new folder"});
  // A folder that merely holds a file the command writes is not an output either.
  const std::string lone = dir.file("lone");
  fs::create_directory(lone);
  test::write_text(lone + "/terrain.json", "{\"mine\": true}");
  expect_input_error([&] { AtomicOutputDir o(lone, kMapLikeKind); },
                     {lone, "not an earlier `map` output"});
  EXPECT_EQ(slurp(lone + "/terrain.json"), "{\"mine\": true}");
  EXPECT_EQ(slurp(out + "/scan.pcd"), "my only scan");
  EXPECT_EQ(slurp(out + "/sub/notes.txt"), "notes");
  EXPECT_EQ(entries(dir.path()), 2u);  // no temporary directory left beside them
}

TEST(AtomicDir, RefusesAtCommitWhenAFileAppearedMeanwhile) {
  ScratchDir dir;
  const std::string out = dir.file("out");
  fs::create_directory(out);  // empty: accepted when the work starts
  AtomicOutputDir o(out, kTestKind);
  write_file_atomically(o.path() + "/a.txt", "new");
  test::write_text(out + "/mine.txt", "user data");
  expect_input_error([&] { o.commit(); }, {out, "mine.txt"});
  EXPECT_EQ(slurp(out + "/mine.txt"), "user data");
}

TEST(AtomicDir, ReplacesAMarkedOutputButNotFilesAddedToIt) {
  ScratchDir dir;
  const std::string out = dir.file("out");
  for (const char* content : {"one", "two"}) {
    AtomicOutputDir o(out, kTestKind);
    fs::create_directory(o.path() + "/layers");
    write_file_atomically(o.path() + "/layers/a.npy", content);
    o.commit();
  }
  EXPECT_EQ(slurp(out + "/layers/a.npy"), "two");
  const std::string marker = slurp(out + "/" + kOutputMarker);
  EXPECT_NE(marker.find("command test"), std::string::npos) << marker;
  EXPECT_NE(marker.find("f layers/a.npy"), std::string::npos) << marker;
  EXPECT_EQ(entries(dir.path()), 1u);
  // Another command's output is terrastride's too; a file added to it by the user is not.
  EXPECT_NO_THROW(check_output_dir(out, kMapLikeKind));
  test::write_text(out + "/layers/mine.txt", "user data");
  expect_input_error([&] { AtomicOutputDir o(out, kTestKind); }, {"layers/mine.txt"});
  EXPECT_EQ(slurp(out + "/layers/mine.txt"), "user data");
}

TEST(AtomicDir, RecognisesAnOutputOfAnOlderVersion) {
  ScratchDir dir;
  const std::string out = dir.file("map");
  fs::create_directories(out + "/layers");
  test::write_text(out + "/terrain.json", "{}");
  test::write_text(out + "/octomap.bt", "tree");
  test::write_text(out + "/layers/elevation.npy", "npy");
  {
    AtomicOutputDir o(out, kMapLikeKind);
    write_file_atomically(o.path() + "/terrain.json", "{\"new\": 1}");
    o.commit();
  }
  EXPECT_EQ(slurp(out + "/terrain.json"), "{\"new\": 1}");
  EXPECT_FALSE(fs::exists(out + "/octomap.bt"));
  // Names read from the folder itself (as report --batch reads its index.json).
  const std::string rep = dir.file("reports");
  fs::create_directory(rep);
  test::write_text(rep + "/index.json", "a.html");
  test::write_text(rep + "/a.html", "page");
  test::write_text(rep + "/b.html", "someone else's page");
  OutputDirKind listed{"report", {"index.json"}, {"index.json"}, {}};
  listed.legacy_listed = [](const std::string& d) {
    return std::vector<std::string>{slurp(d + "/index.json")};
  };
  expect_input_error([&] { check_output_dir(rep, listed); }, {"b.html"});
  fs::remove(rep + "/b.html");
  EXPECT_NO_THROW(check_output_dir(rep, listed));
}

TEST(AtomicDir, EmptyFolderIsReplacedAndALinkToAFolderStaysALink) {
  ScratchDir dir;
  fs::create_directory(dir.file("real"));
  fs::create_directory_symlink("real", dir.file("link"));
  for (int k = 0; k < 2; ++k) {  // an empty folder, then the marked output
    AtomicOutputDir o(dir.file("link"), kTestKind);
    write_file_atomically(o.path() + "/a.txt", std::to_string(k));
    o.commit();
  }
  EXPECT_EQ(file_type(dir.file("link")), S_IFLNK);
  EXPECT_EQ(slurp(dir.file("real/a.txt")), "1");
  EXPECT_EQ(entries(dir.path()), 2u);
}

TEST(AtomicFile, FollowsSymbolicLinks) {
  ScratchDir dir;
  fs::create_directory(dir.file("sub"));
  fs::create_symlink("sub/target.json", dir.file("link.json"));  // relative, dangling at first
  write_file_atomically(dir.file("link.json"), "first");
  write_file_atomically(dir.file("link.json"), "second");
  EXPECT_EQ(file_type(dir.file("link.json")), S_IFLNK);
  EXPECT_EQ(slurp(dir.file("sub/target.json")), "second");
  EXPECT_EQ(entries(dir.path()), 2u);
  EXPECT_EQ(entries(dir.path() / "sub"), 1u);
}

TEST(AtomicFile, KeepsThePermissionsOfTheFileItReplaces) {
  ScratchDir dir;
  const std::string path = dir.file("private.json");
  test::write_text(path, "old");
  ::chmod(path.c_str(), 0600);
  write_file_atomically(path, "new");
  struct stat st;
  ASSERT_EQ(::stat(path.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
}

TEST(AtomicFile, WritesThroughAFifo) {
  ScratchDir dir;
  const std::string fifo = dir.file("pipe");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  // The read end opens first (non-blocking, so a writer that never opens the FIFO cannot hang the
  // test); the thread drains it, bounded by a deadline, while the writer fills the pipe.
  const int rfd = ::open(fifo.c_str(), O_RDONLY | O_NONBLOCK);
  ASSERT_GE(rfd, 0);
  std::string got;
  std::thread reader([&] {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (std::chrono::steady_clock::now() < deadline) {
      pollfd p{rfd, POLLIN, 0};
      if (::poll(&p, 1, 100) <= 0) continue;
      char buf[65536];
      const ssize_t n = ::read(rfd, buf, sizeof buf);
      if (n > 0) got.append(buf, static_cast<size_t>(n));
      if (n == 0 && !got.empty()) break;  // the writer closed it
      if (n == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
      if (n < 0 && errno != EAGAIN) break;
    }
  });
  const std::string payload(200000, 'x');  // more than a pipe holds
  try {
    write_file_atomically(fifo, payload);
  } catch (const InputError& e) {
    ADD_FAILURE() << e.what();
  }
  reader.join();
  ::close(rfd);
  EXPECT_EQ(got.size(), payload.size());
  EXPECT_EQ(file_type(fifo), S_IFIFO);
  EXPECT_EQ(entries(dir.path()), 1u);
}

TEST(AtomicFile, WritesThroughTheNullDevice) {
  ScratchDir dir;
  // As root a broken writer would rename a file over /dev/null itself: use a node of our own then.
  std::string null_dev = ::geteuid() == 0 ? scratch_device(dir, "null", 3) : "/dev/null";
  if (null_dev.empty()) GTEST_SKIP() << "cannot make a device node here";
  EXPECT_NO_THROW(write_file_atomically(null_dev, "discarded"));
  EXPECT_EQ(file_type(null_dev), S_IFCHR);
  EXPECT_EQ(entries(dir.path()), null_dev == "/dev/null" ? 0u : 1u);
}

TEST(AtomicFile, FullDeviceGivesAnErrorNamingThePath) {
  ScratchDir dir;
  std::string full = ::geteuid() == 0 ? scratch_device(dir, "full", 7) : "/dev/full";
  if (full.empty()) GTEST_SKIP() << "cannot make a device node here";
  expect_input_error([&] { write_file_atomically(full, "no room"); },
                     {full, std::strerror(ENOSPC)});
  expect_input_error([&] { write_file_atomically(full, "no room"); }, {full, "write failed"});
  EXPECT_EQ(file_type(full), S_IFCHR);
}

TEST(AtomicFile, WritesToAnOpenDescriptor) {
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  // /dev/fd/N is the process's own descriptor N (as /dev/stdout is 1): written, never replaced.
  EXPECT_NO_THROW(write_file_atomically("/dev/fd/" + std::to_string(fds[1]), "through"));
  EXPECT_TRUE(same_file_as_descriptor("/dev/fd/" + std::to_string(fds[1]), fds[1]));
  ::close(fds[1]);
  char buf[16] = {};
  EXPECT_EQ(::read(fds[0], buf, sizeof buf), 7);
  EXPECT_EQ(std::string(buf), "through");
  ::close(fds[0]);
  // A closed reader is an error naming the path, not a SIGPIPE that kills the process.
  ASSERT_EQ(::pipe(fds), 0);
  ::close(fds[0]);
  const std::string path = "/dev/fd/" + std::to_string(fds[1]);
  expect_input_error([&] { write_file_atomically(path, "nobody reads"); }, {path, "write failed"});
  ::close(fds[1]);
}

TEST(AtomicFile, RefusesSocketsAndBlockDevices) {
  ScratchDir dir;
  const std::string sock = dir.file("sock");
  const int s = ::socket(AF_UNIX, SOCK_STREAM, 0);
  ASSERT_GE(s, 0);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  ASSERT_LT(sock.size(), sizeof addr.sun_path);
  std::strcpy(addr.sun_path, sock.c_str());
  ASSERT_EQ(::bind(s, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  expect_input_error([&] { write_file_atomically(sock, "x"); }, {sock, "socket"});
  expect_input_error([&] { check_output_file(sock); }, {sock, "socket"});
  EXPECT_EQ(file_type(sock), S_IFSOCK);
  ::close(s);
  const std::string blk = dir.file("blk");
  if (::geteuid() == 0 && ::mknod(blk.c_str(), S_IFBLK | 0600, makedev(7, 0)) == 0) {
    expect_input_error([&] { write_file_atomically(blk, "x"); }, {blk, "block device"});
    EXPECT_EQ(file_type(blk), S_IFBLK);
  }
}

TEST(AtomicFile, CheckFailsBeforeAnyWork) {
  ScratchDir dir;
  expect_input_error([&] { check_output_file(dir.file("missing/plan.json")); },
                     {"missing/plan.json", "does not exist"});
  expect_input_error([&] { check_output_file(dir.path().string()); }, {"directory"});
  EXPECT_EQ(check_output_file(dir.file("new.json")).kind, OutputFile::Kind::kNew);
  EXPECT_EQ(entries(dir.path()), 0u);  // the probe leaves nothing
  if (::geteuid() != 0) {              // root writes into read-only folders anyway
    fs::create_directory(dir.file("ro"));
    ::chmod(dir.file("ro").c_str(), 0500);
    expect_input_error([&] { check_output_file(dir.file("ro/plan.json")); }, {"ro/plan.json"});
    expect_input_error([&] { check_output_dir(dir.file("ro/out"), kTestKind); }, {"ro/out"});
    ::chmod(dir.file("ro").c_str(), 0700);
  }
}

TEST(StaleTemporaries, RemovesThoseOfDeadProcessesOnly) {
  ScratchDir dir;
  const std::string dead = std::to_string(dead_pid());
  const std::string live = std::to_string(::getpid());
  const auto make_file = [&](const std::string& name) { test::write_text(dir.file(name), "x"); };
  make_file(".plan.json.tmp-" + dead + "-0-12345");  // killed while writing plan.json: goes
  fs::create_directories(dir.file(".out.tmp-" + dead + "-3-99/layers"));  // a killed map: goes
  make_file(".out.tmp-" + dead + "-3-99/layers/a.npy");
  // Kept: a live process's, another target's, and anything not exactly the pattern.
  const std::vector<std::string> kept = {
      ".plan.json.tmp-" + live + "-0-1", ".other.json.tmp-" + dead + "-0-1",
      "plan.json.tmp-" + dead + "-0-1",  ".plan.json.tmp-" + dead + "-0-1.old",
      ".plan.json.tmp-" + dead + "-x-1", ".plan.json.tmp-" + dead + "-0",
      ".plan.json.tmp." + dead,          "plan.json.tmp." + dead};
  for (const auto& k : kept) make_file(k);

  write_file_atomically(dir.file("plan.json"), "{}");
  EXPECT_FALSE(fs::exists(dir.file(".plan.json.tmp-" + dead + "-0-12345")));
  {
    AtomicOutputDir o(dir.file("out"), kTestKind);
    EXPECT_FALSE(fs::exists(dir.file(".out.tmp-" + dead + "-3-99")));
  }
  for (const auto& k : kept) EXPECT_TRUE(fs::exists(dir.file(k))) << k;
  EXPECT_EQ(entries(dir.path()), kept.size() + 1);  // + plan.json
  EXPECT_EQ(remove_stale_temporaries(dir.path().string(), "plan.json"), 0);
}

}  // namespace
}  // namespace terrastride::perception
