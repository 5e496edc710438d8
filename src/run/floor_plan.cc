#include "omnicml/run/floor_plan.h"

#include <regex>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"

namespace omnicml {

FloorPlan FloorPlanFromWorld(const World& world, int day, std::uint64_t seed) {
  const WorldState state = StateAtDayStart(world, std::max(1, day), seed);
  FloorPlan plan;
  plan.name = world.name;
  plan.min_m = Eigen::Vector2d::Zero();
  plan.max_m = world.size_m;
  for (int i = 0; i < static_cast<int>(world.obstacles.size()); ++i) {
    const Obstacle& o = world.obstacles[static_cast<std::size_t>(i)];
    FloorPlanShape shape;
    switch (o.kind) {
      case ObstacleKind::kWall:
        shape.kind = FloorPlanShape::Kind::kWall;
        break;
      case ObstacleKind::kShelf:
        shape.kind = FloorPlanShape::Kind::kShelf;
        break;
      case ObstacleKind::kBox:
        shape.kind = FloorPlanShape::Kind::kBox;
        break;
    }
    shape.closed = o.closed;
    shape.points_m = ObstacleOutline(world, state, i);
    plan.shapes.push_back(std::move(shape));
  }
  return plan;
}

std::optional<RunWorld> ParseRunWorld(const std::string& input_description) {
  static const std::regex kInput(
      R"(world ([^,\n]+), days (\d+)-(\d+), \d+ frames/day, seed (\d+))");
  std::smatch m;
  if (!std::regex_search(input_description, m, kInput)) return std::nullopt;
  RunWorld w;
  w.world = m[1].str();
  w.last_day = std::stoi(m[3].str());
  w.seed = std::stoull(m[4].str());
  return w;
}

std::optional<RunWorld> ReadRunWorld(const std::filesystem::path& run_dir) {
  const std::string text = ReadTextFile(run_dir / "config.yaml", 1 << 20);
  const auto pos = text.find("# input: ");
  if (pos == std::string::npos) return std::nullopt;
  return ParseRunWorld(text.substr(pos + 9, text.find('\n', pos) - pos - 9));
}

FloorPlan FloorPlanForRunInput(const std::string& input_description) {
  const std::optional<RunWorld> w = ParseRunWorld(input_description);
  if (!w) return {};
  try {
    return FloorPlanFromWorld(LoadWorld(w->world), w->last_day, w->seed);
  } catch (const Error&) {
    return {};
  }
}

}  // namespace omnicml
