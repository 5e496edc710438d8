// Every output flag of every `omnicml` command, taken from the command registry
// (apps/command_registry.h OutputFlags), refuses a path that is not a regular file or
// nothing (or, for directory outputs, a directory or nothing): a FIFO, a socket, a
// directory, a symbolic link (to a regular file or directory), a regular file where a
// directory belongs, and a character device. Paths are nodes created in a private
// temporary directory (the device with mknod, as root only), never /dev/null: should a
// command wrongly accept one, nothing real is replaced. Commands are parsed in process
// with their callbacks replaced by a marker, so a wrong acceptance runs no work; the test
// also checks each node is unchanged afterwards.
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"

namespace omnicml::app {
namespace {
namespace fs = std::filesystem;

// A fresh `omnicml` command line from the registry, every subcommand's work replaced by
// setting *ran.
std::unique_ptr<CLI::App> MakeApp(bool* ran) {
  auto app = std::make_unique<CLI::App>("omnicml");
  app->require_subcommand(1);
  AddGlobalOptions(*app);
  for (const RegisteredCommand& command : CommandRegistry()) command.setup(*app);
  std::function<void(CLI::App*)> replace = [&](CLI::App* a) {
    for (CLI::App* sub : a->get_subcommands([](CLI::App*) { return true; })) {
      if (sub->get_name().empty()) continue;
      sub->callback([ran] { *ran = true; });
      replace(sub);
    }
  };
  replace(app.get());
  return app;
}

class TempDir {
 public:
  TempDir() {
    char pattern[] = "/tmp/omnicml-outflags-XXXXXX";  // short: socket paths are limited
    const char* made = ::mkdtemp(pattern);
    if (made == nullptr) throw Error("mkdtemp failed");
    path_ = made;
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

std::string ReadText(const fs::path& p) {
  std::ifstream in(p);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void MakeSocket(const fs::path& p) {
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  ASSERT_GE(fd, 0);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  ASSERT_LT(p.string().size(), sizeof addr.sun_path);
  std::snprintf(addr.sun_path, sizeof addr.sun_path, "%s", p.c_str());
  ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  ::close(fd);
}

// One kind of path an output must refuse: how to make it in `dir`, and a fingerprint
// (type and, for links, target and the target's content) that must not change.
struct BadNode {
  std::string name;
  std::function<fs::path(const fs::path& dir)> make;
};

std::string Fingerprint(const fs::path& p) {
  struct stat st {};
  if (::lstat(p.c_str(), &st) != 0) return "missing";
  std::string out = std::to_string(st.st_mode & S_IFMT) + ":" + std::to_string(st.st_ino);
  if (S_ISLNK(st.st_mode)) {
    const fs::path target = fs::read_symlink(p);
    out += "->" + target.string();
    if (fs::is_regular_file(target)) out += "=" + ReadText(target);
    if (fs::is_directory(target))
      out += "=dir:" + std::to_string(std::distance(fs::directory_iterator(target), {}));
  }
  if (S_ISDIR(st.st_mode)) {
    out += "=dir:" + std::to_string(std::distance(fs::directory_iterator(p), {}));
  }
  return out;
}

std::vector<BadNode> NodesForFiles() {
  return {
      {"fifo",
       [](const fs::path& d) {
         const fs::path p = d / "fifo";
         ::mkfifo(p.c_str(), 0666);
         return p;
       }},
      {"socket",
       [](const fs::path& d) {
         const fs::path p = d / "sock";
         MakeSocket(p);
         return p;
       }},
      {"directory",
       [](const fs::path& d) {
         const fs::path p = d / "dir";
         fs::create_directory(p);
         return p;
       }},
      {"symlink to a regular file",
       [](const fs::path& d) {
         std::ofstream(d / "real.txt") << "precious\n";
         const fs::path p = d / "link";
         fs::create_symlink(d / "real.txt", p);
         return p;
       }},
      {"dangling symlink",
       [](const fs::path& d) {
         const fs::path p = d / "dangling";
         fs::create_symlink(d / "nowhere", p);
         return p;
       }},
  };
}

std::vector<BadNode> NodesForDirectories() {
  return {
      {"fifo",
       [](const fs::path& d) {
         const fs::path p = d / "fifo";
         ::mkfifo(p.c_str(), 0666);
         return p;
       }},
      {"socket",
       [](const fs::path& d) {
         const fs::path p = d / "sock";
         MakeSocket(p);
         return p;
       }},
      {"regular file",
       [](const fs::path& d) {
         const fs::path p = d / "file";
         std::ofstream(p) << "precious\n";
         return p;
       }},
      {"symlink to a directory",
       [](const fs::path& d) {
         fs::create_directory(d / "realdir");
         std::ofstream(d / "realdir" / "keep.txt") << "precious\n";
         const fs::path p = d / "link";
         fs::create_directory_symlink(d / "realdir", p);
         return p;
       }},
  };
}

// Parses `omnicml [<global>] <command...> <flag> <path>`; returns the parse error's
// message ("" when the parse succeeded) and sets *ran when the command would have run.
std::string ParseWith(const OutputFlag& flag, const fs::path& path, const std::string& global,
                      bool* ran) {
  std::unique_ptr<CLI::App> app = MakeApp(ran);
  std::vector<std::string> args;
  if (!global.empty()) args.push_back(global);
  args.insert(args.end(), flag.command.begin(), flag.command.end());
  args.push_back(flag.flag);
  args.push_back(path.string());
  std::vector<std::string> reversed(args.rbegin(), args.rend());
  try {
    app->parse(reversed);
  } catch (const CLI::ParseError& e) {
    return e.what();
  }
  return {};
}

// Parses `omnicml [<global>] <command...> <flag> <path>` and expects a refusal naming the
// path before any work, with the node unchanged.
void ExpectRefused(const OutputFlag& flag, const fs::path& path, const std::string& kind,
                   const std::string& global = "") {
  std::string where = global.empty() ? "" : global + " ";
  for (const std::string& c : flag.command) where += c + " ";
  where += flag.flag + " (" + kind + ")";
  const std::string before = Fingerprint(path);
  bool ran = false;
  const std::string message = ParseWith(flag, path, global, &ran);
  EXPECT_FALSE(ran) << where << ": the command ran";
  EXPECT_NE(message.find(path.string()), std::string::npos)
      << where << ": message does not name the path: '" << message << "'";
  EXPECT_EQ(message.find('\n'), std::string::npos) << where << ": " << message;
  EXPECT_EQ(Fingerprint(path), before) << where << ": the node changed";
}

// Every option whose name says it writes something is registered as an output flag, so
// a new output flag cannot escape the refusal test below.
TEST(OutputFlags, EveryOutputLikeOptionIsRegisteredAsOutput) {
  bool ran = false;
  std::unique_ptr<CLI::App> app = MakeApp(&ran);
  std::vector<std::string> flagged;
  for (const OutputFlag& f : OutputFlags(*app)) flagged.push_back(f.flag);
  // An output-like option missing from the registry's listing fails.
  std::function<void(CLI::App*, std::string)> check = [&](CLI::App* a, std::string path) {
    std::vector<std::string> mine;
    for (const OutputFlag& f : OutputFlags(*a)) {
      if (f.command.empty()) mine.push_back(f.flag);
    }
    for (const CLI::Option* o : a->get_options()) {
      // A flag (no value) names no path.
      if (o->get_expected_max() == 0 || o->get_name().empty() || o->get_positional()) continue;
      const std::string name = o->get_name();
      if (!LooksLikeOutputFlag(name.substr(name.find_first_not_of('-')))) continue;
      EXPECT_NE(std::find(mine.begin(), mine.end(), name), mine.end())
          << "'omnicml " << path << name
          << "' looks like an output but is not added with AddOutputFile/AddOutputDirectory";
    }
    for (CLI::App* sub : a->get_subcommands([](CLI::App*) { return true; })) {
      if (!sub->get_name().empty()) check(sub, path + sub->get_name() + " ");
    }
  };
  check(app.get(), "");
  // The commands known to write files are all there (the registry is complete).
  for (const char* expected : {"--out", "--map-out", "--trajectory-out", "--preview", "--overlay",
                               "--csv", "--save-calibration", "--make-sample"}) {
    EXPECT_NE(std::find(flagged.begin(), flagged.end(), expected), flagged.end()) << expected;
  }
  EXPECT_GE(flagged.size(), 17u);
}

// Every output file flag refuses FIFOs, sockets, directories and symbolic links.
TEST(OutputFlags, FileOutputsRefuseNonRegularPaths) {
  bool ran = false;
  const std::vector<OutputFlag> flags = OutputFlags(*MakeApp(&ran));
  int checked = 0;
  for (const OutputFlag& flag : flags) {
    if (flag.kind != OutputKind::kFile) continue;
    for (const BadNode& node : NodesForFiles()) {
      TempDir dir;
      const fs::path path = node.make(dir.path());
      ExpectRefused(flag, path, node.name);
      ++checked;
    }
  }
  EXPECT_GE(checked, 9 * 5);
}

// Every output directory flag refuses FIFOs, sockets, regular files and symbolic links.
TEST(OutputFlags, DirectoryOutputsRefuseNonDirectories) {
  bool ran = false;
  const std::vector<OutputFlag> flags = OutputFlags(*MakeApp(&ran));
  int checked = 0;
  for (const OutputFlag& flag : flags) {
    if (flag.kind != OutputKind::kDirectory) continue;
    for (const BadNode& node : NodesForDirectories()) {
      TempDir dir;
      const fs::path path = node.make(dir.path());
      ExpectRefused(flag, path, node.name);
      ++checked;
    }
  }
  EXPECT_GE(checked, 8 * 4);
}

// With the global --follow-output-symlinks, every output file flag accepts a symbolic link
// to a regular file (the parse does not refuse the path) and still refuses links to a
// FIFO, a directory or nothing, and the other non-regular nodes; directory outputs still
// refuse links. Without the flag (a new parse), the link is refused again.
TEST(OutputFlags, FollowOutputSymlinksAcceptsOnlyLinksToRegularFiles) {
  const std::string kFollow = "--follow-output-symlinks";
  bool ran = false;
  const std::vector<OutputFlag> flags = OutputFlags(*MakeApp(&ran));
  int accepted = 0;
  for (const OutputFlag& flag : flags) {
    if (flag.kind == OutputKind::kDirectory) {
      for (const BadNode& node : NodesForDirectories()) {
        TempDir dir;
        ExpectRefused(flag, node.make(dir.path()), node.name, kFollow);
      }
      continue;
    }
    TempDir dir;
    std::ofstream(dir.path() / "real.txt") << "precious\n";
    const fs::path link = dir.path() / "link";
    fs::create_symlink(dir.path() / "real.txt", link);
    const fs::path chain = dir.path() / "chain";
    fs::create_symlink(link, chain);
    for (const fs::path& path : {link, chain}) {
      const std::string before = Fingerprint(path);
      bool flag_ran = false;
      const std::string message = ParseWith(flag, path, kFollow, &flag_ran);
      // Other required arguments may be missing; the path itself must not be the problem.
      EXPECT_EQ(message.find(path.string()), std::string::npos)
          << kFollow << " " << flag.flag << " refused a link to a regular file: " << message;
      EXPECT_EQ(Fingerprint(path), before);
      ++accepted;
    }
    ExpectRefused(flag, link, "symlink to a regular file, without the flag");
    ::mkfifo((dir.path() / "fifo").c_str(), 0666);
    fs::create_symlink(dir.path() / "fifo", dir.path() / "to_fifo");
    ExpectRefused(flag, dir.path() / "to_fifo", "symlink to a FIFO", kFollow);
    fs::create_directory(dir.path() / "realdir");
    fs::create_directory_symlink(dir.path() / "realdir", dir.path() / "to_dir");
    ExpectRefused(flag, dir.path() / "to_dir", "symlink to a directory", kFollow);
    for (const BadNode& node : NodesForFiles()) {
      if (node.name == "symlink to a regular file") continue;
      TempDir other;
      ExpectRefused(flag, node.make(other.path()), node.name, kFollow);
    }
  }
  EXPECT_GE(accepted, 2 * 9);
}

// Every output flag refuses a character device: a device node made in a private
// directory (the same major/minor as /dev/null), never the real one. Needs root (mknod).
TEST(OutputFlags, EveryOutputRefusesACharacterDevice) {
  if (::geteuid() != 0) {
    GTEST_SKIP() << "not root: cannot mknod a private character device (the FIFO, socket, "
                    "directory and link cases still run)";
  }
  bool ran = false;
  for (const OutputFlag& flag : OutputFlags(*MakeApp(&ran))) {
    TempDir dir;
    const fs::path path = dir.path() / "null";
    ASSERT_EQ(::mknod(path.c_str(), S_IFCHR | 0666, makedev(1, 3)), 0);
    ExpectRefused(flag, path, "character device");
  }
}

// The built binary turns the refusal into exit code 2 with a one-line message naming
// the path (a FIFO given to export --out, a socket to run --map-out).
TEST(OutputFlags, BinaryExitsTwoNamingThePath) {
  const fs::path binary = fs::path(OMNICML_BINARY_DIR) / "omnicml";
  if (!fs::exists(binary)) GTEST_SKIP() << "omnicml binary not built";
  TempDir dir;
  const fs::path fifo = dir.path() / "out.png";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0666), 0);
  const fs::path sock = dir.path() / "map.bin";
  MakeSocket(sock);
  for (const std::string& args :
       {"export no-such-map --out " + fifo.string(),
        "run --world home_store --frames-per-day 5 --quiet --map-out " + sock.string()}) {
    const fs::path err = dir.path() / "stderr.txt";
    const int status =
        std::system((binary.string() + " " + args + " >/dev/null 2>" + err.string()).c_str());
    ASSERT_TRUE(WIFEXITED(status));
    EXPECT_EQ(WEXITSTATUS(status), 2) << args;
    const std::string text = ReadText(err);
    EXPECT_NE(text.find(args.substr(args.rfind(' ') + 1)), std::string::npos) << text;
    EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 1) << text;
  }
  struct stat st {};
  ASSERT_EQ(::lstat(fifo.c_str(), &st), 0);
  EXPECT_TRUE(S_ISFIFO(st.st_mode));
  ASSERT_EQ(::lstat(sock.c_str(), &st), 0);
  EXPECT_TRUE(S_ISSOCK(st.st_mode));
}

// The binary with --follow-output-symlinks writes a map and a trajectory through links
// to regular files: the links stay links, the files they lead to get the new content;
// without the flag the same command exits 2 and changes nothing.
TEST(OutputFlags, BinaryWritesThroughLinksWhenAsked) {
  const fs::path binary = fs::path(OMNICML_BINARY_DIR) / "omnicml";
  if (!fs::exists(binary)) GTEST_SKIP() << "omnicml binary not built";
  TempDir dir;
  std::ofstream(dir.path() / "map.real") << "old map\n";
  std::ofstream(dir.path() / "traj.real") << "old trajectory\n";
  fs::create_symlink("map.real", dir.path() / "map.link");
  fs::create_symlink(dir.path() / "traj.real", dir.path() / "traj.link");
  const std::string command = " run --world home_store --frames-per-day 5 --quiet --map-out " +
                              (dir.path() / "map.link").string() + " --trajectory-out " +
                              (dir.path() / "traj.link").string() + " >/dev/null 2>" +
                              (dir.path() / "stderr.txt").string();
  int status = std::system((binary.string() + command).c_str());
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 2) << ReadText(dir.path() / "stderr.txt");
  EXPECT_EQ(ReadText(dir.path() / "map.real"), "old map\n");
  status = std::system((binary.string() + " --follow-output-symlinks" + command).c_str());
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0) << ReadText(dir.path() / "stderr.txt");
  EXPECT_TRUE(fs::is_symlink(dir.path() / "map.link"));
  EXPECT_TRUE(fs::is_symlink(dir.path() / "traj.link"));
  EXPECT_EQ(ReadText(dir.path() / "map.real").rfind("OMNICML", 0), 0u);
  EXPECT_NE(ReadText(dir.path() / "traj.real"), "old trajectory\n");
  EXPECT_FALSE(ReadText(dir.path() / "traj.real").empty());
  // Nothing else was left beside the files (no temporaries, no lock files).
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir.path())) names.push_back(e.path().filename());
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"map.link", "map.real", "stderr.txt", "traj.link",
                                             "traj.real"}));
}

}  // namespace
}  // namespace omnicml::app
