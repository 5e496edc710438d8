#include "omnicml/baselines/mcl/occupancy_grid.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <queue>
#include <sstream>

#include <yaml-cpp/yaml.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/yaml_io.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

double DistancePointSegment(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                            const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double len2 = ab.squaredNorm();
  double t = len2 > 0 ? (p - a).dot(ab) / len2 : 0.0;
  t = std::clamp(t, 0.0, 1.0);
  return (a + t * ab - p).norm();
}

bool PointInPolygon(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& p) {
  bool inside = false;
  for (std::size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
    const auto& a = poly[i];
    const auto& b = poly[j];
    if ((a.y() > p.y()) != (b.y() > p.y()) &&
        p.x() < (b.x() - a.x()) * (p.y() - a.y()) / (b.y() - a.y()) + a.x()) {
      inside = !inside;
    }
  }
  return inside;
}

std::string Fmt(double v) {
  std::ostringstream os;
  os.precision(17);
  os << v;
  return os.str();
}

// Reads the next whitespace-separated token of a PGM header, skipping '#' comments.
bool NextPgmToken(std::istream& in, std::string* token) {
  token->clear();
  int c;
  while ((c = in.get()) != EOF) {
    if (c == '#') {
      while ((c = in.get()) != EOF && c != '\n') {
      }
      continue;
    }
    if (std::isspace(c)) {
      if (!token->empty()) return true;
      continue;
    }
    token->push_back(static_cast<char>(c));
  }
  return !token->empty();
}

// A PGM (P5 binary or P2 ASCII, maxval <= 255) as rows top to bottom.
struct Pgm {
  int width = 0;
  int height = 0;
  int maxval = 255;
  std::vector<std::uint8_t> pixels;
};

Pgm ReadPgm(const std::string& path) {
  // A regular file of bounded size, read once (no FIFO or device).
  std::istringstream in(ReadTextFile(path, kMaxImageFileBytes, "PGM image"));
  std::string magic, w, h, m;
  if (!NextPgmToken(in, &magic) || (magic != "P5" && magic != "P2")) {
    throw Error(StrCat(path, ": not a PGM image (expected magic P5 or P2)"));
  }
  if (!NextPgmToken(in, &w) || !NextPgmToken(in, &h) || !NextPgmToken(in, &m)) {
    throw Error(StrCat(path, ": truncated PGM header"));
  }
  Pgm pgm;
  try {
    pgm.width = std::stoi(w);
    pgm.height = std::stoi(h);
    pgm.maxval = std::stoi(m);
  } catch (const std::exception&) {
    throw Error(StrCat(path, ": malformed PGM header"));
  }
  if (pgm.width < 1 || pgm.height < 1 || pgm.maxval < 1 || pgm.maxval > 255) {
    throw Error(StrCat(path, ": unsupported PGM size or maxval (need 8-bit grey, maxval <= 255)"));
  }
  const std::size_t n = static_cast<std::size_t>(pgm.width) * pgm.height;
  if (n > kMaxImagePixels) {
    throw Error(StrCat(path, ": PGM of ", pgm.width, "x", pgm.height, " pixels is larger than ",
                       kMaxImagePixels));
  }
  pgm.pixels.resize(n);
  if (magic == "P5") {
    in.read(reinterpret_cast<char*>(pgm.pixels.data()), static_cast<std::streamsize>(n));
    if (static_cast<std::size_t>(in.gcount()) != n) {
      throw Error(StrCat(path, ": truncated PGM data (", in.gcount(), " of ", n, " bytes)"));
    }
  } else {
    std::string tok;
    for (std::size_t i = 0; i < n; ++i) {
      if (!NextPgmToken(in, &tok)) throw Error(StrCat(path, ": truncated PGM data"));
      int v = 0;
      try {
        v = std::stoi(tok);
      } catch (const std::exception&) {
        throw Error(StrCat(path, ": bad PGM pixel value '", tok, "'"));
      }
      if (v < 0 || v > pgm.maxval) throw Error(StrCat(path, ": PGM pixel value out of range"));
      pgm.pixels[i] = static_cast<std::uint8_t>(v);
    }
  }
  if (pgm.maxval != 255) {
    for (auto& p : pgm.pixels) p = static_cast<std::uint8_t>(std::lround(p * 255.0 / pgm.maxval));
  }
  return pgm;
}

double YamlDouble(const YAML::Node& root, const std::string& key, const std::string& file) {
  const YAML::Node n = root[key];
  if (!n) throw Error(StrCat(file, ": ", key, ": missing key"));
  try {
    const double v = n.as<double>();
    if (!std::isfinite(v)) throw Error("");
    return v;
  } catch (const std::exception&) {
    throw Error(StrCat(file, ":", n.Mark().line + 1, ": ", key, ": not a finite number"));
  }
}

}  // namespace

// ----------------------------------------------------------------------------- grid

OccupancyGrid::OccupancyGrid(int width, int height, double resolution_m,
                             const Eigen::Vector2d& origin_m, CellState fill)
    : width_(width), height_(height), resolution_m_(resolution_m), origin_m_(origin_m) {
  if (width < 1 || height < 1) throw Error(StrCat("OccupancyGrid: size ", width, "x", height));
  if (!(resolution_m > 0) || !std::isfinite(resolution_m)) {
    throw Error(StrCat("OccupancyGrid: resolution_m must be > 0, got ", resolution_m));
  }
  cells_.assign(static_cast<std::size_t>(width) * height, fill);
}

CellIndex OccupancyGrid::CellOf(const Eigen::Vector2d& p) const {
  return {static_cast<int>(std::floor((p.x() - origin_m_.x()) / resolution_m_)),
          static_cast<int>(std::floor((p.y() - origin_m_.y()) / resolution_m_))};
}

Eigen::Vector2d OccupancyGrid::CellCenter(const CellIndex& c) const {
  return origin_m_ + Eigen::Vector2d((c.x + 0.5) * resolution_m_, (c.y + 0.5) * resolution_m_);
}

CellState OccupancyGrid::At(const CellIndex& c) const {
  return InBounds(c) ? cells_[Linear(c)] : CellState::kUnknown;
}

void OccupancyGrid::Set(const CellIndex& c, CellState s) {
  OMNICML_CHECK(InBounds(c)) << "cell " << c.x << "," << c.y;
  cells_[Linear(c)] = s;
}

std::vector<int> OccupancyGrid::FreeCells() const {
  std::vector<int> out;
  for (int i = 0; i < static_cast<int>(cells_.size()); ++i) {
    if (cells_[i] == CellState::kFree) out.push_back(i);
  }
  return out;
}

std::optional<CellIndex> OccupancyGrid::CastRay(const Eigen::Vector2d& from_m, double heading_rad,
                                                double max_range_m) const {
  // Amanatides & Woo voxel traversal in cell units.
  const double dx = std::cos(heading_rad), dy = std::sin(heading_rad);
  const Eigen::Vector2d p = (from_m - origin_m_) / resolution_m_;
  CellIndex c{static_cast<int>(std::floor(p.x())), static_cast<int>(std::floor(p.y()))};
  const int step_x = dx > 0 ? 1 : -1, step_y = dy > 0 ? 1 : -1;
  constexpr double kInf = std::numeric_limits<double>::infinity();
  const double t_dx = dx != 0 ? std::abs(1.0 / dx) : kInf;
  const double t_dy = dy != 0 ? std::abs(1.0 / dy) : kInf;
  double t_x = dx != 0 ? ((dx > 0 ? (c.x + 1 - p.x()) : (p.x() - c.x)) * t_dx) : kInf;
  double t_y = dy != 0 ? ((dy > 0 ? (c.y + 1 - p.y()) : (p.y() - c.y)) * t_dy) : kInf;
  const double t_max = max_range_m / resolution_m_;
  double t = 0;
  while (t <= t_max) {
    const CellState s = At(c);
    if (s == CellState::kOccupied) return c;
    if (s == CellState::kUnknown) return std::nullopt;
    if (t_x < t_y) {
      t = t_x;
      t_x += t_dx;
      c.x += step_x;
    } else {
      t = t_y;
      t_y += t_dy;
      c.y += step_y;
    }
  }
  return std::nullopt;
}

bool OccupancyGrid::LineOfSight(const CellIndex& a, const CellIndex& b) const {
  // Supercover-free Bresenham between cell centres; b may be occupied.
  int x0 = a.x, y0 = a.y;
  const int dx = std::abs(b.x - a.x), dy = -std::abs(b.y - a.y);
  const int sx = a.x < b.x ? 1 : -1, sy = a.y < b.y ? 1 : -1;
  int err = dx + dy;
  while (true) {
    if (x0 == b.x && y0 == b.y) return true;
    if (!IsFree({x0, y0})) return false;
    const int e2 = 2 * err;
    if (e2 >= dy) {
      err += dy;
      x0 += sx;
    }
    if (e2 <= dx) {
      err += dx;
      y0 += sy;
    }
  }
}

// ----------------------------------------------------------------------------- world

void OccupancyGridFromWorldOptions::Validate() const {
  if (!(resolution_m > 0) || !std::isfinite(resolution_m)) {
    throw Error(StrCat("occupancy grid: resolution_m must be > 0, got ", resolution_m));
  }
  if (!(inflate_m >= 0) || !std::isfinite(inflate_m)) {
    throw Error(StrCat("occupancy grid: inflate_m must be >= 0, got ", inflate_m));
  }
  if (border_cells < 0) throw Error(StrCat("occupancy grid: border_cells must be >= 0"));
}

OccupancyGrid MakeOccupancyGrid(const World& world, const WorldState& state,
                                const OccupancyGridFromWorldOptions& options) {
  options.Validate();
  const double res = options.resolution_m;
  const int b = options.border_cells;
  const int w = static_cast<int>(std::ceil(world.size_m.x() / res - 1e-9)) + 2 * b;
  const int h = static_cast<int>(std::ceil(world.size_m.y() / res - 1e-9)) + 2 * b;
  OccupancyGrid grid(w, h, res, Eigen::Vector2d(-b * res, -b * res), CellState::kFree);
  const double touch = res * std::sqrt(0.5) + options.inflate_m;
  std::vector<std::vector<Eigen::Vector2d>> outlines;
  std::vector<bool> closed;
  for (std::size_t i = 0; i < world.obstacles.size(); ++i) {
    if (!state.present[i]) continue;  // taken away (layout changes)
    outlines.push_back(ObstacleOutline(world, state, static_cast<int>(i)));
    closed.push_back(world.obstacles[i].closed);
  }
  for (int iy = 0; iy < h; ++iy) {
    for (int ix = 0; ix < w; ++ix) {
      const Eigen::Vector2d p = grid.CellCenter({ix, iy});
      bool occ = p.x() < options.inflate_m || p.y() < options.inflate_m ||
                 p.x() > world.size_m.x() - options.inflate_m ||
                 p.y() > world.size_m.y() - options.inflate_m;
      for (std::size_t o = 0; o < outlines.size() && !occ; ++o) {
        const auto& pts = outlines[o];
        if (closed[o] && pts.size() >= 3 && PointInPolygon(pts, p)) {
          occ = true;
          break;
        }
        const std::size_t n = closed[o] ? pts.size() : pts.size() - 1;
        for (std::size_t k = 0; k < n; ++k) {
          if (DistancePointSegment(p, pts[k], pts[(k + 1) % pts.size()]) <= touch) {
            occ = true;
            break;
          }
        }
      }
      if (occ) grid.Set({ix, iy}, CellState::kOccupied);
    }
  }
  return grid;
}

// ----------------------------------------------------------------------------- files

void SaveOccupancyGrid(const OccupancyGrid& grid, const std::string& yaml_path) {
  const fs::path yaml(yaml_path);
  const fs::path pgm = fs::path(yaml).replace_extension(".pgm");
  {
    AtomicFile file(pgm);  // temporary, fsync, rename (common/file_io.h)
    std::ostream& out = file.stream();
    out << "P5\n# omnicml occupancy grid\n" << grid.width() << " " << grid.height() << "\n255\n";
    std::vector<std::uint8_t> row(grid.width());
    for (int r = 0; r < grid.height(); ++r) {
      const int iy = grid.height() - 1 - r;
      for (int ix = 0; ix < grid.width(); ++ix) {
        switch (grid.At({ix, iy})) {
          case CellState::kOccupied:
            row[ix] = 0;
            break;
          case CellState::kFree:
            row[ix] = 254;
            break;
          case CellState::kUnknown:
            row[ix] = 205;
            break;
        }
      }
      out.write(reinterpret_cast<const char*>(row.data()),
                static_cast<std::streamsize>(row.size()));
    }
    file.Commit();  // throws "<path>: write error: ..."
  }
  std::ostringstream out;
  out << "image: " << pgm.filename().string() << "\n"
      << "resolution: " << Fmt(grid.resolution_m()) << "\n"
      << "origin: [" << Fmt(grid.origin_m().x()) << ", " << Fmt(grid.origin_m().y()) << ", 0.0]\n"
      << "negate: 0\n"
      << "occupied_thresh: 0.65\n"
      << "free_thresh: 0.196\n"
      << "mode: trinary\n";
  WriteFileAtomic(yaml, out.str());
}

OccupancyGrid LoadOccupancyGrid(const std::string& yaml_path) {
  const std::string text = ReadTextFile(yaml_path, kMaxTextFileBytes, "occupancy grid");
  YAML::Node root;
  try {
    root = LoadYaml(text, yaml_path);
  } catch (const YAML::Exception& e) {
    throw Error(StrCat(yaml_path, ":", e.mark.line + 1, ": YAML error: ", e.msg));
  }
  if (!root.IsMap()) throw Error(StrCat(yaml_path, ": expected a map of map_server keys"));
  static const std::vector<std::string> kKeys = {
      "image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode"};
  for (const auto& kv : root) {
    const std::string key = kv.first.as<std::string>();
    if (std::find(kKeys.begin(), kKeys.end(), key) == kKeys.end()) {
      throw Error(StrCat(yaml_path, ":", kv.first.Mark().line + 1, ": ", key, ": unknown key"));
    }
  }
  if (!root["image"]) throw Error(StrCat(yaml_path, ": image: missing key"));
  const std::string image = root["image"].as<std::string>();
  const double resolution = YamlDouble(root, "resolution", yaml_path);
  if (!(resolution > 0)) throw Error(StrCat(yaml_path, ": resolution: must be > 0"));
  const YAML::Node origin = root["origin"];
  if (!origin) throw Error(StrCat(yaml_path, ": origin: missing key"));
  if (!origin.IsSequence() || origin.size() != 3) {
    throw Error(StrCat(yaml_path, ":", origin.Mark().line + 1, ": origin: expected [x, y, yaw]"));
  }
  double o[3];
  for (int i = 0; i < 3; ++i) {
    try {
      o[i] = origin[i].as<double>();
    } catch (const std::exception&) {
      throw Error(StrCat(yaml_path, ":", origin.Mark().line + 1, ": origin: not a number"));
    }
    if (!std::isfinite(o[i])) throw Error(StrCat(yaml_path, ": origin: not finite"));
  }
  if (std::abs(o[2]) > 1e-12) throw Error(StrCat(yaml_path, ": origin: yaw must be 0"));
  const double negate_d = YamlDouble(root, "negate", yaml_path);
  if (negate_d != 0 && negate_d != 1) throw Error(StrCat(yaml_path, ": negate: must be 0 or 1"));
  const double occ_t = YamlDouble(root, "occupied_thresh", yaml_path);
  const double free_t = YamlDouble(root, "free_thresh", yaml_path);
  if (occ_t < 0 || occ_t > 1) throw Error(StrCat(yaml_path, ": occupied_thresh: not in [0, 1]"));
  if (free_t < 0 || free_t > 1) throw Error(StrCat(yaml_path, ": free_thresh: not in [0, 1]"));
  if (free_t > occ_t) throw Error(StrCat(yaml_path, ": free_thresh: greater than occupied_thresh"));
  if (root["mode"] && root["mode"].as<std::string>() != "trinary") {
    throw Error(StrCat(yaml_path, ": mode: only 'trinary' is supported, got '",
                       root["mode"].as<std::string>(), "'"));
  }
  fs::path image_path(image);
  if (image_path.is_relative()) image_path = fs::path(yaml_path).parent_path() / image_path;
  const Pgm pgm = ReadPgm(image_path.string());
  OccupancyGrid grid(pgm.width, pgm.height, resolution, Eigen::Vector2d(o[0], o[1]));
  for (int r = 0; r < pgm.height; ++r) {
    for (int ix = 0; ix < pgm.width; ++ix) {
      const int p = pgm.pixels[static_cast<std::size_t>(r) * pgm.width + ix];
      const double occ = negate_d == 1 ? p / 255.0 : (255.0 - p) / 255.0;
      CellState s = CellState::kUnknown;
      if (occ > occ_t) {
        s = CellState::kOccupied;
      } else if (occ < free_t) {
        s = CellState::kFree;
      }
      grid.Set({ix, pgm.height - 1 - r}, s);
    }
  }
  return grid;
}

// ----------------------------------------------------------------------------- visibility

void VisibilityOptions::Validate() const {
  if (!(max_ray_range_m > 0) || !std::isfinite(max_ray_range_m)) {
    throw Error(StrCat("visibility: max_ray_range_m must be > 0, got ", max_ray_range_m));
  }
  if (!(max_distance_m > 0) || !std::isfinite(max_distance_m)) {
    throw Error(StrCat("visibility: max_distance_m must be > 0, got ", max_distance_m));
  }
  if (!(max_distance_from_reference_m >= 0) || !std::isfinite(max_distance_from_reference_m)) {
    throw Error(StrCat("visibility: max_distance_from_reference_m must be >= 0, got ",
                       max_distance_from_reference_m));
  }
  if (!(max_view_angle_rad > 0) || max_view_angle_rad > kPi + 1e-12) {
    throw Error(
        StrCat("visibility: max_view_angle_rad must be in (0, pi], got ", max_view_angle_rad));
  }
}

std::vector<int> VisibilityArea(const OccupancyGrid& grid, const Eigen::Vector2d& position_m,
                                double axis_rad, const VisibilityOptions& options,
                                CellIndex* lambda_out) {
  options.Validate();
  // [W]: lambda_j is the first occupied cell on the optical axis.
  const auto lambda = grid.CastRay(position_m, axis_rad, options.max_ray_range_m);
  if (!lambda) return {};
  if (lambda_out != nullptr) *lambda_out = *lambda;
  const Eigen::Vector2d lambda_m = grid.CellCenter(*lambda);
  const Eigen::Vector2d axis(std::cos(axis_rad), std::sin(axis_rad));
  const double cos_max = std::cos(options.max_view_angle_rad);
  auto admissible = [&](const CellIndex& c) {
    if (!grid.IsFree(c)) return false;
    const Eigen::Vector2d d = lambda_m - grid.CellCenter(c);
    const double dist = d.norm();
    if (dist > options.max_distance_m) return false;
    if (dist > 0 && d.dot(axis) / dist < cos_max - 1e-12) return false;
    return grid.LineOfSight(c, *lambda);
  };
  // Seed: the admissible 8-neighbours of lambda_j.
  std::vector<char> seen(grid.cells().size(), 0);
  std::queue<CellIndex> queue;
  std::vector<int> area;
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      const CellIndex c{lambda->x + dx, lambda->y + dy};
      if (!grid.InBounds(c) || seen[grid.Linear(c)]) continue;
      seen[grid.Linear(c)] = 1;
      if (admissible(c)) {
        queue.push(c);
        area.push_back(grid.Linear(c));
      }
    }
  }
  // Constrained region growing over 8-connected cells.
  while (!queue.empty()) {
    const CellIndex c = queue.front();
    queue.pop();
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        if (dx == 0 && dy == 0) continue;
        const CellIndex n{c.x + dx, c.y + dy};
        if (!grid.InBounds(n) || seen[grid.Linear(n)]) continue;
        seen[grid.Linear(n)] = 1;
        if (admissible(n)) {
          queue.push(n);
          area.push_back(grid.Linear(n));
        }
      }
    }
  }
  if (options.max_distance_from_reference_m > 0) {
    const double r2 = options.max_distance_from_reference_m * options.max_distance_from_reference_m;
    std::erase_if(area, [&](int i) {
      return (grid.CellCenter(grid.FromLinear(i)) - position_m).squaredNorm() > r2;
    });
  }
  std::sort(area.begin(), area.end());
  return area;
}

}  // namespace omnicml
