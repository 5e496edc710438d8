// Integration test of omnicml_node under a real ROS 1 master: a simulated 2-day log with
// frames 0.1 m apart is exported to a bag and played to the node by omnicml_ros_play
// (lockstep; the node holds the first day's frames to measure the frame step and restates
// its per-frame options for it, as the offline run does from the log); the poses the
// node publishes must have the position error of the engine run offline on the same log
// (mean and max within 1e-6 m: the run is the same computation, the bag's quaternions
// change odometry angles in their last bits), every frame must get a pose, the
// ~save_map service and the save on shutdown must write a map that loads back with the
// offline run's views, and ~forgetting_static must reach the engine. Processes run in their own
// process groups, are given a time limit and are killed as groups at the end. Skipped when
// rosmaster is not installed.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/ros/rosbag_io.h"
#include "omnicml/run/run_config.h"
#include "omnicml/sim/simulator.h"
#include "ros/ros1.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

bool OnPath(const std::string& program) {
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path ? path : "");
  for (std::string dir; std::getline(dirs, dir, ':');)
    if (!dir.empty() && ::access((fs::path(dir) / program).c_str(), X_OK) == 0) return true;
  return false;
}

int FreePort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = 0;
  ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr));
  socklen_t len = sizeof(addr);
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  ::close(fd);
  return ntohs(addr.sin_port);
}

// A child process in its own process group, output to a file; killed as a group.
class Child {
 public:
  Child(const std::vector<std::string>& argv, const fs::path& output) : name_(argv[0]) {
    pid_ = ::fork();
    if (pid_ == 0) {
      ::setpgid(0, 0);
      const int fd = ::open(output.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      ::dup2(fd, 1);
      ::dup2(fd, 2);
      std::vector<char*> args;
      for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
      args.push_back(nullptr);
      ::execvp(args[0], args.data());
      ::_exit(127);
    }
    ::setpgid(pid_, pid_);
  }
  ~Child() { Kill(); }
  // Waits at most timeout_s for the exit; returns the exit code, or -1 on timeout.
  int Wait(double timeout_s) {
    const auto deadline =
        std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (pid_ > 0) {
      int status = 0;
      const pid_t r = ::waitpid(pid_, &status, WNOHANG);
      if (r == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      }
      if (std::chrono::steady_clock::now() > deadline) return -1;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return -1;
  }
  void Signal(int sig) {
    if (pid_ > 0) ::kill(pid_, sig);
  }
  void Kill() {
    if (pid_ <= 0) return;
    ::kill(-pid_, SIGTERM);
    if (Wait(5.0) < 0) {
      ::kill(-pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
    pid_ = -1;
  }

 private:
  std::string name_;
  pid_t pid_ = -1;
};

std::string Slurp(const fs::path& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

struct Errors {
  int frames = 0;
  double mean_m = 0.0, max_m = 0.0;
};

// Offline: the engine over the log with the options `omnicml run` derives for a new map
// (the frame step); position errors against the truth by stamp.
Errors RunOffline(const fs::path& log, std::size_t* views, std::string* note) {
  RunInput input;
  input.log_dirs = {log.string()};
  CmlEngine engine(ResolveNewMapOptions(OptionOverrides{}, input, note));
  LogReader reader(log.string());
  Frame f;
  int session = -1;
  Errors e;
  while (reader.Next(&f)) {
    if (f.session_index != session) engine.BeginSession(reader.Session(session = f.session_index));
    const FrameResult r = engine.ProcessFrame(f);
    const double d = (r.estimate->strongest.mean.head<2>() - f.map_T_robot_truth->head<2>()).norm();
    e.mean_m += d;
    e.max_m = std::max(e.max_m, d);
    ++e.frames;
  }
  e.mean_m /= e.frames;
  *views = engine.model().NumViews();
  return e;
}

// The node's poses (omnicml_ros_play's CSV) against the log's truth, matched by stamp.
Errors NodeErrors(const fs::path& poses_csv, const fs::path& log, double offset_s) {
  std::map<long long, Pose2> truth;  // stamp in ns -> truth
  {
    LogReaderOptions o;
    o.load_images = false;
    LogReader reader(log.string(), o);
    Frame f;
    while (reader.Next(&f))
      truth[std::llround((f.stamp_s + offset_s) * 1e9)] = *f.map_T_robot_truth;
  }
  std::ifstream in(poses_csv);
  std::string line;
  std::getline(in, line);
  Errors e;
  while (std::getline(in, line)) {
    std::stringstream row(line);
    std::string cell;
    std::vector<double> v;
    while (std::getline(row, cell, ',')) v.push_back(std::stod(cell));
    const auto it = truth.lower_bound(std::llround(v[0] * 1e9) - 2);
    if (it == truth.end() || std::abs(it->first - std::llround(v[0] * 1e9)) > 2) continue;
    const double d = std::hypot(v[1] - it->second.x(), v[2] - it->second.y());
    e.mean_m += d;
    e.max_m = std::max(e.max_m, d);
    ++e.frames;
  }
  if (e.frames > 0) e.mean_m /= e.frames;
  return e;
}

// The node localizes a played bag exactly as the offline run does, answers ~save_map and
// ~forgetting_static and saves on shutdown; both maps load back with the offline run's views.
TEST(RosNode, LocalizesAPlayedBagLikeTheOfflineRun) {
  if (!OnPath("rosmaster"))
    GTEST_SKIP() << "SKIPPED: rosmaster is not installed (Debian python3-rosmaster; "
                    "scripts/setup.sh installs it)";
  const fs::path tmp = fs::temp_directory_path() / StrCat("omnicml_ros_node_test_", ::getpid());
  fs::create_directories(tmp);
  {
    SimulatorOptions options;
    options.days = 2;
    options.frames_per_day = 60;
    options.output = ImageKind::kPanorama;
    options.seed = 4;
    options.step_m = 0.1;  // k = 2: twice the motion noise, half the evidence per frame
    SimulatedFrameSource source(options);
    LogWriter writer((tmp / "log").string());
    WriteFrames(source, writer);
    writer.Finish();
  }
  std::size_t offline_views = 0;
  std::string note;
  const Errors offline = RunOffline(tmp / "log", &offline_views, &note);
  ASSERT_NE(note.find("motion noise a1..a4 x 2"), std::string::npos) << note;
  const RosbagExportSummary exported =
      ExportRosbag((tmp / "log").string(), (tmp / "log.bag").string());

  const int port = FreePort();
  const std::string uri = StrCat("http://127.0.0.1:", port);
  ::setenv("ROS_MASTER_URI", uri.c_str(), 1);
  ::setenv("ROS_IP", "127.0.0.1", 1);
  ::unsetenv("ROS_HOSTNAME");
  ::setenv("ROS_HOME", (tmp / "ros_home").c_str(), 1);
  ::setenv("ROS_LOG_DIR", (tmp / "ros_log").c_str(), 1);
  const std::string bin = OMNICML_BINARY_DIR;
  Child master({"rosmaster", "--core", "-p", std::to_string(port)}, tmp / "master.txt");
  const fs::path map = tmp / "map.bin";
  Child node({bin + "/omnicml_node", "__name:=omnicml_node", "_map_out:=" + map.string(),
              "_queue_size:=1000", "_views_every_frames:=30"},
             tmp / "node.txt");
  Child player({bin + "/omnicml_ros_play", (tmp / "log.bag").string(), "--lockstep", "--poses-out",
                (tmp / "poses.csv").string(), "--timeout", "30", "--hold", "300"},
               tmp / "player.txt");
  const int player_rc = player.Wait(90.0);
  ASSERT_EQ(player_rc, 0) << "player: " << Slurp(tmp / "player.txt")
                          << "\nnode: " << Slurp(tmp / "node.txt")
                          << "\nmaster: " << Slurp(tmp / "master.txt");

  // ~save_map from a client of our own.
  std::string message;
  EXPECT_TRUE(ros1::CallTrigger("/omnicml_node/save_map", 10.0, &message)) << message;
  EXPECT_EQ(LoadEngine(map.string())->model().NumViews(), offline_views);
  fs::remove(map);
  // ~forgetting_static reaches the engine: the map saved on shutdown carries the mode.
  EXPECT_TRUE(ros1::CallTrigger("/omnicml_node/forgetting_static", 10.0, &message)) << message;
  ros1::Shutdown();

  node.Signal(SIGINT);
  EXPECT_EQ(node.Wait(30.0), 0) << Slurp(tmp / "node.txt");
  // The node's log (its console stays on for the whole run) names the frame step's factors.
  const std::string node_log = Slurp(tmp / "node.txt");
  EXPECT_NE(node_log.find("over the first 60 frames: motion noise a1..a4 x 2"), std::string::npos)
      << node_log;
  EXPECT_NE(node_log.find("120 processed, 0 dropped"), std::string::npos) << node_log;
  master.Kill();

  const Errors live = NodeErrors(tmp / "poses.csv", tmp / "log", exported.stamp_offset_s);
  EXPECT_EQ(live.frames, offline.frames) << Slurp(tmp / "player.txt") << Slurp(tmp / "node.txt");
  EXPECT_NEAR(live.mean_m, offline.mean_m, 1e-6);
  EXPECT_NEAR(live.max_m, offline.max_m, 1e-6);
  const std::unique_ptr<CmlEngine> saved = LoadEngine(map.string());  // saved on shutdown
  EXPECT_EQ(saved->model().NumViews(), offline_views);
  EXPECT_EQ(saved->counters().frames, offline.frames);
  EXPECT_EQ(saved->options().model.forgetting.mode, ForgettingMode::kStatic);
  std::cout << "offline: " << offline.frames << " frames, mean error " << offline.mean_m
            << " m, max " << offline.max_m << " m; node: " << live.frames << " poses, mean "
            << live.mean_m << " m, max " << live.max_m << " m\n";
  fs::remove_all(tmp);
}

}  // namespace
}  // namespace omnicml
