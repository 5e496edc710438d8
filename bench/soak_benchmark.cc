// Soak benchmark: many simulated days of one world through the whole
// `omnicml run` path (simulator -> engine -> run recorder writing a real run directory),
// one process, and after every day a row of what must stay bounded by the map rather
// than by the run's length:
//
//   views, components   the map (EnvironmentModel)
//   events_held         events in the model's ring (<= model.events.max_events)
//   events_logged       events since the start (events.csv has them all)
//   map_bytes           EncodeEngine size = the saved map file's size
//   rss_mb, anon_mb, peak_mb
//                       resident set now, its anonymous part (heap and stacks, without
//                       the pages of shared libraries) and its high-water mark (Linux
//                       VmRSS, RssAnon, VmHWM; read before the map is encoded)
//   heap_mb             bytes in live heap blocks (jemalloc stats.allocated, or glibc
//                       mallinfo2): what the program holds, without the allocator's
//                       free space and fragmentation
//   run_dir_mb          every file in the run directory so far (frames.csv and
//                       events.csv are streamed to temporaries there)
//   frames, localized, mean_err_m   that day's frames and error (over its localized
//                       frames; localized counts them, so coverage is localized/frames)
//   day_s               wall time of the day (simulation + engine + recording)
//
// Usage:
//   build/soak_benchmark [--world home_store] [--days 30] [--frames-per-day 300]
//                        [--forgetting active] [--seed 1] [--threads 2]
//                        [--config ENGINE.yaml] [--out DIR] [--csv FILE]
// The run directory (DIR, default a fresh directory under /tmp) is committed at the end
// like `omnicml run`'s, so its final size is the last row's run_dir_mb plus the files
// written at Commit (config.yaml, days.csv, report.html, TUM files), printed last.
// Results apart from the timing and memory columns are deterministic.
#include <malloc.h>
#if defined(OMNICML_HAVE_JEMALLOC)
#include <jemalloc/jemalloc.h>
#endif

#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/experiments/run_experiment.h"
#include "omnicml/run/engine_driver.h"
#include "omnicml/run/run_recorder.h"
#include "omnicml/run/run_report.h"

namespace omnicml {
namespace {

// "VmRSS" / "VmHWM" of /proc/self/status in MiB; 0 where there is none (not Linux).
double StatusMiB(const char* key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const std::string prefix = std::string(key) + ":";
  while (std::getline(in, line)) {
    if (line.rfind(prefix, 0) == 0) return std::stod(line.substr(prefix.size())) / 1024.0;
  }
  return 0.0;
}

// Bytes in live heap blocks, MiB: jemalloc's stats.allocated when the program allocates
// with jemalloc, glibc's mallinfo2 (uordblks + hblkhd) otherwise; 0 where neither.
double LiveHeapMiB() {
#if defined(OMNICML_HAVE_JEMALLOC)
  std::uint64_t epoch = 1;
  std::size_t size = sizeof epoch;
  mallctl("epoch", &epoch, &size, &epoch, size);  // refresh the statistics
  std::size_t allocated = 0;
  size = sizeof allocated;
  if (mallctl("stats.allocated", &allocated, &size, nullptr, 0) != 0) return 0.0;
  return static_cast<double>(allocated) / (1024.0 * 1024.0);
#elif defined(__GLIBC__)
  const struct mallinfo2 mi = mallinfo2();
  return static_cast<double>(mi.uordblks + mi.hblkhd) / (1024.0 * 1024.0);
#else
  return 0.0;
#endif
}

double DirectoryMiB(const std::filesystem::path& dir) {
  std::uintmax_t bytes = 0;
  std::error_code ec;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(dir, ec)) {
    if (entry.is_regular_file(ec)) bytes += entry.file_size(ec);
  }
  return static_cast<double>(bytes) / (1024.0 * 1024.0);
}

struct DayRow {
  int day = 0;
  std::size_t views = 0, components = 0, events_held = 0;
  std::uint64_t events_logged = 0;
  std::size_t map_bytes = 0;
  double rss_mb = 0, anon_mb = 0, heap_mb = 0, peak_mb = 0, run_dir_mb = 0;
  std::int64_t frames = 0, localized = 0;
  double mean_err_m = 0;
  double day_s = 0;
};

class SoakMeter {
 public:
  SoakMeter(const RunRecorder& recorder, std::filesystem::path run_dir)
      : recorder_(recorder), run_dir_(std::move(run_dir)) {}

  void EndOfDay(const CmlEngine& engine, int day) {
    DayRow row;
    row.day = day;
    row.rss_mb = StatusMiB("VmRSS");
    row.anon_mb = StatusMiB("RssAnon");
    row.peak_mb = StatusMiB("VmHWM");
    row.heap_mb = LiveHeapMiB();
    const EnvironmentModel& model = engine.model();
    row.views = model.NumViews();
    row.components = model.NumComponents();
    row.events_held = model.events().size();
    row.events_logged = model.events_logged();
    row.map_bytes = EncodeEngine(engine).size();
    row.run_dir_mb = DirectoryMiB(run_dir_);
    double err_sum = 0;
    for (std::size_t i = next_record_; i < recorder_.records().size(); ++i) {
      const FrameRecord& r = recorder_.records()[i];
      ++row.frames;
      if (r.has_estimate) ++row.localized;
      if (std::isfinite(r.position_error_m)) err_sum += r.position_error_m;
    }
    next_record_ = recorder_.records().size();
    row.mean_err_m = row.localized > 0 ? err_sum / static_cast<double>(row.localized) : 0.0;
    const auto now = std::chrono::steady_clock::now();
    row.day_s = std::chrono::duration<double>(now - day_start_).count();
    day_start_ = now;
    rows_.push_back(row);
    std::fprintf(stderr, "soak: day %d: %zu views, rss %.1f MiB, map %.2f MiB, run dir %.2f MiB\n",
                 day + 1, row.views, row.rss_mb, row.map_bytes / (1024.0 * 1024.0), row.run_dir_mb);
  }

  const std::vector<DayRow>& rows() const { return rows_; }

 private:
  const RunRecorder& recorder_;
  std::filesystem::path run_dir_;
  std::size_t next_record_ = 0;
  std::chrono::steady_clock::time_point day_start_ = std::chrono::steady_clock::now();
  std::vector<DayRow> rows_;
};

std::string FormatRows(const std::vector<DayRow>& rows, char sep) {
  std::ostringstream os;
  const char* names[] = {"day",        "views",  "components", "events_held", "events_logged",
                         "map_mb",     "rss_mb", "anon_mb",    "heap_mb",     "peak_mb",
                         "run_dir_mb", "frames", "localized",  "mean_err_m",  "day_s"};
  for (std::size_t i = 0; i < std::size(names); ++i)
    os << (i ? std::string(1, sep) : "") << names[i];
  os << "\n";
  char buf[512];
  for (const DayRow& r : rows) {
    std::snprintf(
        buf, sizeof buf,
        "%d%c%zu%c%zu%c%zu%c%llu%c%.3f%c%.1f%c%.1f%c%.1f%c%.1f%c%.2f%c%lld%c%lld%c%.3f%c%.1f\n",
        r.day + 1, sep, r.views, sep, r.components, sep, r.events_held, sep,
        static_cast<unsigned long long>(r.events_logged), sep, r.map_bytes / (1024.0 * 1024.0), sep,
        r.rss_mb, sep, r.anon_mb, sep, r.heap_mb, sep, r.peak_mb, sep, r.run_dir_mb, sep,
        static_cast<long long>(r.frames), sep, static_cast<long long>(r.localized), sep,
        r.mean_err_m, sep, r.day_s);
    os << buf;
  }
  return os.str();
}

int Main(int argc, char** argv) {
  CLI::App app{"soak_benchmark: memory, map and run-directory size per simulated day"};
  RunSettings settings;
  settings.input.world = "home_store";
  settings.input.days = 30;
  settings.input.frames_per_day = 300;
  std::string forgetting = "active";
  int threads = 2;
  std::string out_dir, csv_path;
  app.add_option("--world", settings.input.world, "built-in world");
  app.add_option("--days", settings.input.days, "simulated days")->check(CLI::Range(1, 3650));
  app.add_option("--frames-per-day", settings.input.frames_per_day, "frames per day")
      ->check(CLI::Range(1, 1000000));
  app.add_option("--seed", settings.input.seed, "simulator seed");
  app.add_option("--forgetting", forgetting, "active|passive|static");
  app.add_option("--threads", threads, "engine threads (1 or 2)")->check(CLI::Range(1, 2));
  app.add_option("--config", settings.overrides.config_path, "engine options YAML");
  app.add_option("--out", out_dir, "run directory (default: a new directory in /tmp)");
  app.add_option("--csv", csv_path, "also write the table as CSV here (atomically)");
  CLI11_PARSE(app, argc, argv);

  if (out_dir.empty()) {
    out_dir =
        (std::filesystem::temp_directory_path() / ("omnicml-soak-" + std::to_string(::getpid())))
            .string();
  }
  settings.overrides.forgetting = forgetting;
  settings.overrides.threads = threads;
  settings.input.Validate();
  CmlEngine engine(ResolveEngineOptions(settings.overrides));
  std::unique_ptr<FrameSource> source = OpenFrameSource(settings.input);
  RunRecorderOptions ro;
  ro.run_dir = out_dir;
  ro.title = "soak_benchmark";
  ro.input_description = settings.input.Describe();
  RunRecorder recorder(ro);
  SoakMeter meter(recorder, out_dir);
  ProgressOptions progress;
  progress.quiet = true;
  progress.total_frames = CountFrames(settings.input, *source);  // as `omnicml run`: one Reserve
  const auto start = std::chrono::steady_clock::now();
  const RunSummary summary =
      RunEngineOverSource(engine, *source, &recorder, progress,
                          [&meter](CmlEngine& e, int session) { meter.EndOfDay(e, session); });
  meter.EndOfDay(engine, summary.sessions - 1);
  engine.Finish();
  recorder.Commit(engine);
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  std::cout << "soak: " << settings.input.Describe() << ", forgetting " << forgetting
            << ", threads " << threads << ", " << summary.frames << " frames, "
            << FormatFixed(wall_s, 1) << " s\n";
  std::cout << FormatRows(meter.rows(), '\t');
  std::cout << "run directory after Commit: " << out_dir << " "
            << FormatFixed(DirectoryMiB(out_dir), 2) << " MiB\n";
  if (!csv_path.empty()) WriteFileAtomic(csv_path, FormatRows(meter.rows(), ','));
  return 0;
}

}  // namespace
}  // namespace omnicml

int main(int argc, char** argv) {
  try {
    return omnicml::Main(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "soak_benchmark: " << e.what() << "\n";
    return 2;
  }
}
