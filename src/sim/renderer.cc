#include "omnicml/sim/renderer.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/imgproc.hpp>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "omnicml/common/common.h"
#include "omnicml/geometry/planar_geometry.h"

namespace omnicml {
namespace {

constexpr double kGridCellM = 1.0;       // segment grid cell size
constexpr double kLightCellM = 0.1;      // light grid cell size
constexpr double kWindowNudgeM = 0.004;  // windows are drawn this much in front of walls
constexpr double kDegToRad = kPi / 180.0;

// Fast 64-bit hash of a seed and two integer coordinates (murmur3 finaliser).
inline std::uint64_t Hash(std::uint64_t seed, std::int64_t a, std::int64_t b) {
  std::uint64_t z = seed ^ (static_cast<std::uint64_t>(a) * 0x9E3779B97F4A7C15ULL) ^
                    (static_cast<std::uint64_t>(b) * 0xC2B2AE3D27D4EB4FULL);
  z ^= z >> 33;
  z *= 0xff51afd7ed558ccdULL;
  z ^= z >> 33;
  z *= 0xc4ceb9fe1a85ec53ULL;
  z ^= z >> 33;
  return z;
}
inline float Unit(std::uint64_t h) { return static_cast<float>(h >> 40) * (1.0f / 16777216.0f); }
// floor() as an integer without a libm call (inputs are far inside the int64 range).
inline std::int64_t FloorInt(double v) {
  const std::int64_t i = static_cast<std::int64_t>(v);
  return i - (v < static_cast<double>(i) ? 1 : 0);
}

struct Rgb {
  float r, g, b;
};
inline Rgb Mix(const Rgb& a, const Rgb& b, float t) {
  return {a.r + (b.r - a.r) * t, a.g + (b.g - a.g) * t, a.b + (b.b - a.b) * t};
}
inline Rgb Scale(const Rgb& a, float s) { return {a.r * s, a.g * s, a.b * s}; }
inline Rgb ToRgb(const std::array<double, 3>& c) {
  return {static_cast<float>(c[0]), static_cast<float>(c[1]), static_cast<float>(c[2])};
}

// 64 saturated goods colours (HSV hue wheel x 4 value/saturation levels).
const std::array<Rgb, 64>& Palette() {
  static const std::array<Rgb, 64> palette = [] {
    std::array<Rgb, 64> p{};
    for (int i = 0; i < 64; ++i) {
      const float h = static_cast<float>(i % 16) / 16.0f * 6.0f;
      const float s = (i / 16) % 2 == 0 ? 0.85f : 0.55f;
      const float v = i / 32 == 0 ? 235.0f : 165.0f;
      const int sector = static_cast<int>(h);
      const float f = h - sector;
      const float pp = v * (1 - s), q = v * (1 - s * f), t = v * (1 - s * (1 - f));
      Rgb c{};
      switch (sector % 6) {
        case 0:
          c = {v, t, pp};
          break;
        case 1:
          c = {q, v, pp};
          break;
        case 2:
          c = {pp, v, t};
          break;
        case 3:
          c = {pp, q, v};
          break;
        case 4:
          c = {t, pp, v};
          break;
        default:
          c = {v, pp, q};
          break;
      }
      p[i] = c;
    }
    return p;
  }();
  return palette;
}

// A texture as used at render time: its spec with the state's seed and cleared flag.
struct RuntimeTexture {
  TextureSpec spec;
  Rgb base{};
  bool cleared = false;
};

// Colour of a procedural texture at surface coordinate u (m along the outline, or x on
// the floor) and v (m above the floor, or y on the floor).
Rgb SampleTexture(const RuntimeTexture& t, double u, double v) {
  const TextureSpec& s = t.spec;
  const Rgb base = t.base;
  Rgb pattern = base;
  switch (s.kind) {
    case TextureKind::kPlain:
      return base;
    case TextureKind::kGoods: {
      const double spacing = s.shelf_spacing_m;
      const std::int64_t level = FloorInt(v / spacing);
      const double zl = v - static_cast<double>(level) * spacing;
      constexpr double kBoard = 0.035;
      if (zl < kBoard) {
        pattern = {118, 120, 128};  // shelf board
        break;
      }
      const Rgb back = Scale(base, 0.45f);
      if (t.cleared) {
        // Empty shelf: pegboard back with a sparse grid of holes.
        const bool hole = std::fmod(std::abs(u), 0.05) < 0.012 && std::fmod(zl, 0.05) < 0.012;
        pattern = hole ? Scale(back, 0.6f) : back;
        break;
      }
      const std::uint64_t lh = Hash(s.seed, level, 7);
      const double width = s.cell_m * (0.35 + 1.3 * Unit(lh));
      const double shifted = u + Unit(lh << 3) * width;
      const std::int64_t k = FloorInt(shifted / width);
      const double fu = shifted / width - static_cast<double>(k);
      const std::uint64_t ph = Hash(s.seed, level, k);
      const double fill = (spacing - kBoard) * (0.5 + 0.45 * Unit(ph << 7));
      if (zl - kBoard > fill || Unit(ph << 17) < 0.08f) {
        pattern = back;  // above the goods, or a gap
      } else if (fu < 0.05 || fu > 0.95) {
        pattern = Scale(Palette()[ph & 63], 0.6f);  // package edge
      } else {
        pattern = Palette()[ph & 63];
        const double rel = (zl - kBoard) / fill;
        if (rel > 0.35 && rel < 0.6 && fu > 0.25 && fu < 0.75 && (ph & 0x100)) {
          pattern = Palette()[(ph >> 24) & 63];  // the package's label
        }
      }
      break;
    }
    case TextureKind::kLabels: {
      const double cw = 2.0 * s.cell_m, ch = 1.6 * s.cell_m;
      const std::int64_t i = FloorInt(u / cw), j = FloorInt(v / ch);
      const std::uint64_t h = Hash(s.seed, i, j);
      if ((h & 3) == 0) break;
      const double fu = u / cw - static_cast<double>(i), fv = v / ch - static_cast<double>(j);
      const double u0 = 0.05 + 0.3 * Unit(h << 2), u1 = u0 + 0.25 + 0.35 * Unit(h << 12);
      const double v0 = 0.05 + 0.3 * Unit(h << 22), v1 = v0 + 0.2 + 0.4 * Unit(h << 32);
      if (fu > u0 && fu < u1 && fv > v0 && fv < v1) {
        pattern = Palette()[(h >> 42) & 63];
        // A text line: a darker band in the lower part of the label.
        if (fv > v0 + 0.15 * (v1 - v0) && fv < v0 + 0.3 * (v1 - v0) && (h & 4))
          pattern = Scale(pattern, 0.35f);
      }
      break;
    }
    case TextureKind::kNoise: {
      const std::int64_t i = FloorInt(u / s.cell_m), j = FloorInt(v / s.cell_m);
      pattern = Scale(base, 0.7f + 0.6f * Unit(Hash(s.seed, i, j)));
      break;
    }
    case TextureKind::kTiles: {
      const double inv = 1.0 / s.cell_m;
      const double fu = u * inv, fv = v * inv;
      const std::int64_t i = FloorInt(fu), j = FloorInt(fv);
      const double gu = fu - static_cast<double>(i), gv = fv - static_cast<double>(j);
      if (gu < 0.04 || gv < 0.04) {
        pattern = Scale(base, 0.55f);
      } else {
        const std::uint64_t h = Hash(s.seed, i, j);
        pattern = Scale(base, 0.8f + 0.4f * Unit(h));
        if (((i + j) & 1) == 0) pattern = Scale(pattern, 0.88f);
      }
      break;
    }
  }
  return Mix(base, pattern, static_cast<float>(s.contrast));
}

// Samples a texture down one surface column (fixed u, varying height v), caching what
// depends only on u and the texture cell row (goods level, label or noise row), so most
// rows cost a few comparisons. Gives exactly SampleTexture's colours.
class ColumnSampler {
 public:
  ColumnSampler(const RuntimeTexture& t, double u)
      : t_(t),
        u_(u),
        inv_spacing_(1.0 / t.spec.shelf_spacing_m),
        inv_label_h_(1.0 / (1.6 * t.spec.cell_m)),
        inv_cell_(1.0 / t.spec.cell_m) {}

  Rgb operator()(double v) {
    const TextureSpec& s = t_.spec;
    switch (s.kind) {
      case TextureKind::kGoods: {
        if (t_.cleared) return SampleTexture(t_, u_, v);
        const double spacing = s.shelf_spacing_m;
        const std::int64_t level = FloorInt(v * inv_spacing_);
        const double zl = v - static_cast<double>(level) * spacing;
        constexpr double kBoard = 0.035;
        if (zl < kBoard)
          return Mix(t_.base, Rgb{118, 120, 128}, static_cast<float>(s.contrast));  // board
        if (level != key_) {
          key_ = level;
          const std::uint64_t lh = Hash(s.seed, level, 7);
          const double width = s.cell_m * (0.35 + 1.3 * Unit(lh));
          const double shifted = u_ + Unit(lh << 3) * width;
          const std::int64_t k = FloorInt(shifted / width);
          const double fu = shifted / width - static_cast<double>(k);
          const std::uint64_t ph = Hash(s.seed, level, k);
          fill_ = (spacing - kBoard) * (0.5 + 0.45 * Unit(ph << 7));
          gap_ = Unit(ph << 17) < 0.08f;
          edge_ = fu < 0.05 || fu > 0.95;
          label_ = fu > 0.25 && fu < 0.75 && (ph & 0x100);
          const float c = static_cast<float>(s.contrast);
          back_ = Mix(t_.base, Scale(t_.base, 0.45f), c);
          product_ = Mix(t_.base, edge_ ? Scale(Palette()[ph & 63], 0.6f) : Palette()[ph & 63], c);
          label_color_ = Mix(t_.base, Palette()[(ph >> 24) & 63], c);
        }
        if (zl - kBoard > fill_ || gap_) return back_;
        if (!edge_ && label_) {
          const double rel = (zl - kBoard) / fill_;
          if (rel > 0.35 && rel < 0.6) return label_color_;
        }
        return product_;
      }
      case TextureKind::kLabels: {
        const double cw = 2.0 * s.cell_m;
        const std::int64_t j = FloorInt(v * inv_label_h_);
        if (j != key_) {
          key_ = j;
          const std::int64_t i = FloorInt(u_ / cw);
          const std::uint64_t h = Hash(s.seed, i, j);
          const double fu = u_ / cw - static_cast<double>(i);
          const double u0 = 0.05 + 0.3 * Unit(h << 2), u1 = u0 + 0.25 + 0.35 * Unit(h << 12);
          v0_ = 0.05 + 0.3 * Unit(h << 22);
          v1_ = v0_ + 0.2 + 0.4 * Unit(h << 32);
          inside_u_ = (h & 3) != 0 && fu > u0 && fu < u1;
          text_ = (h & 4) != 0;
          const float c = static_cast<float>(s.contrast);
          label_color_ = Mix(t_.base, Palette()[(h >> 42) & 63], c);
          product_ = Mix(t_.base, Scale(Palette()[(h >> 42) & 63], 0.35f), c);
        }
        if (!inside_u_) return t_.base;
        const double fv = v * inv_label_h_ - static_cast<double>(j);
        if (!(fv > v0_ && fv < v1_)) return t_.base;
        if (text_ && fv > v0_ + 0.15 * (v1_ - v0_) && fv < v0_ + 0.3 * (v1_ - v0_)) return product_;
        return label_color_;
      }
      case TextureKind::kNoise: {
        const std::int64_t j = FloorInt(v * inv_cell_);
        if (j != key_) {
          key_ = j;
          const std::int64_t i = FloorInt(u_ * inv_cell_);
          back_ = Mix(t_.base, Scale(t_.base, 0.7f + 0.6f * Unit(Hash(s.seed, i, j))),
                      static_cast<float>(s.contrast));
        }
        return back_;
      }
      default:
        return SampleTexture(t_, u_, v);
    }
  }

 private:
  const RuntimeTexture& t_;
  double u_;
  double inv_spacing_, inv_label_h_, inv_cell_;
  std::int64_t key_ = std::numeric_limits<std::int64_t>::min();
  double fill_ = 0, v0_ = 0, v1_ = 0;
  bool gap_ = false, edge_ = false, label_ = false, inside_u_ = false, text_ = false;
  Rgb back_{}, product_{}, label_color_{};
};

// A vertical surface piece: obstacle face or window.
struct Segment {
  Eigen::Vector2d a, b;   // end points, m
  double z0 = 0, z1 = 0;  // bottom and top, m
  double u0 = 0;          // texture coordinate at a, m along the outline
  double length = 0;
  float face_shade = 1.0f;
  int texture = -1;  // index into textures_ (obstacles); -1 for windows
  int window = -1;   // index into world windows
};

// Which rows of the column being rendered are filled; lo/hi bound the unfilled ones.
struct ColumnState {
  std::uint8_t* filled;
  int lo;  // no unfilled row above lo
  int hi;  // no unfilled row below hi
};

// One hit along a ray.
struct Hit {
  double t;     // distance along the ray, m (windows nudged nearer)
  double u;     // texture coordinate along the surface
  int segment;  // index into segments_, or -1 for a person
  int person;   // index into people, or -1
  Eigen::Vector2d point;
};

// Rounds and saturates a colour value to a byte.
inline std::uint8_t Sat(float v) {
  const int i = static_cast<int>(v + 0.5f);
  return static_cast<std::uint8_t>(i < 0 ? 0 : (i > 255 ? 255 : i));
}

}  // namespace

OmniCalibration SimulatedCalibration(const CameraSpec& camera) {
  OmniCalibration c;
  c.center_x_px = (camera.ring_width_px - 1) * 0.5;
  c.center_y_px = (camera.ring_height_px - 1) * 0.5;
  c.inner_radius_px = camera.inner_radius_px;
  c.outer_radius_px = camera.outer_radius_px;
  c.azimuth0_rad = 0.0;
  c.direction = RingDirection::kCounterClockwise;
  c.elevation = ElevationMapping::kLinear;
  c.panorama_width = camera.panorama_width_px;
  c.panorama_height = camera.panorama_height_px;
  return c;
}

struct Renderer::Impl {
  World world;
  WorldState state;
  OmniUnwrapper unwrapper;
  int width = 0, height = 0;
  double cam_h = 0;
  double elev_max = 0, elev_step = 0;
  std::vector<double> row_tan;         // tan(elevation) per row, decreasing
  std::vector<double> row_neg_tan;     // -tan, increasing (for binary search)
  std::vector<double> row_plane_dist;  // horizontal distance to floor / ceiling per row
  double max_height = 0;               // tallest thing in the world, m
  double max_range = 0;

  std::vector<RuntimeTexture> textures;  // per obstacle
  RuntimeTexture floor_tex, ceiling_tex;
  std::vector<Segment> segments;
  int grid_w = 0, grid_h = 0;
  std::vector<int>
      cell_start;  // CSR: segments of cell i are cell_segs[cell_start[i] .. cell_start[i+1])
  std::vector<int> cell_segs;

  int light_w = 0, light_h = 0;
  std::vector<float> light;        // intensity per light cell
  std::vector<std::uint8_t> lamp;  // 0 none, 1 lamp off, 2 lamp on

  // The lit floor and ceiling (with lamps) baked into BGR rasters (nearest cell), rebuilt
  // with the lights: a fine raster for near rows and a 4x coarser one (which stays in
  // cache) for rows whose pixels cover more than half a coarse cell.
  struct BakedPlanes {
    double cell_m = 0.025;
    int w = 0, h = 0;
    std::vector<std::uint8_t> floor_bgr, ceiling_bgr;
  };
  BakedPlanes fine, coarse;
  std::vector<char> row_coarse;  // per row: use `coarse`
  bool built = false;            // Build ran once (later Builds rebuild what changed)

  std::vector<std::int8_t> noise_table;
  std::size_t noise_period = 0;

  Impl(const World& w, std::uint64_t noise_seed)
      : world(w),
        unwrapper(SimulatedCalibration(w.camera), w.camera.ring_width_px, w.camera.ring_height_px) {
    const CameraSpec& c = world.camera;
    width = c.panorama_width_px;
    height = c.panorama_height_px;
    cam_h = c.height_m;
    elev_max = c.elevation_max_deg * kDegToRad;
    elev_step = (c.elevation_max_deg - c.elevation_min_deg) * kDegToRad / height;
    for (int r = 0; r < height; ++r) {
      const double e = elev_max - (r + 0.5) * elev_step;
      const double tn = std::tan(e);
      row_tan.push_back(tn);
      row_neg_tan.push_back(-tn);
      if (tn < -1e-9) {
        row_plane_dist.push_back(cam_h / -tn);
      } else if (tn > 1e-9) {
        row_plane_dist.push_back((world.ceiling_height_m - cam_h) / tn);
      } else {
        row_plane_dist.push_back(std::numeric_limits<double>::infinity());
      }
    }
    max_height = world.ceiling_height_m;
    for (const auto& o : world.obstacles) max_height = std::max(max_height, o.height_m);
    for (const auto& win : world.windows) max_height = std::max(max_height, win.top_m);
    max_height = std::max(max_height, world.people.height_m);
    max_range = 1.5 * world.size_m.norm() + 1.0;
    floor_tex.spec = world.floor;
    floor_tex.base = ToRgb(world.floor.color_rgb);
    ceiling_tex.spec = world.ceiling;
    ceiling_tex.base = ToRgb(world.ceiling.color_rgb);

    // Sensor noise table: Box-Muller normals from a splitmix stream (portable bytes).
    const double sigma = c.noise_sigma_gray;
    noise_period = 65536;
    const std::size_t n =
        static_cast<std::size_t>(c.ring_width_px) * c.ring_height_px * 3 +
        static_cast<std::size_t>(std::max(c.panorama_width_px * c.panorama_height_px * 3, 0)) +
        noise_period;
    noise_table.resize(n);
    std::uint64_t stream = MixSeed(noise_seed, 0x5E45ULL);
    for (std::size_t i = 0; i < n; i += 2) {
      stream = MixSeed(stream, i);
      const double u1 = (static_cast<double>(stream >> 11) + 1.0) * 0x1.0p-53;
      const double u2 = static_cast<double>(MixSeed(stream, 1) >> 11) * 0x1.0p-53;
      const double rad = std::sqrt(-2.0 * std::log(u1)) * sigma;
      noise_table[i] = static_cast<std::int8_t>(
          std::lround(std::clamp(rad * std::cos(kTwoPi * u2), -127.0, 127.0)));
      if (i + 1 < n) {
        noise_table[i + 1] = static_cast<std::int8_t>(
            std::lround(std::clamp(rad * std::sin(kTwoPi * u2), -127.0, 127.0)));
      }
    }
  }

  void Build(const WorldState& s) {
    OMNICML_CHECK(s.obstacle_offset_m.size() == world.obstacles.size() &&
                  s.present.size() == world.obstacles.size() &&
                  s.light_on.size() == world.lights.size() &&
                  s.light_scale.size() == world.lights.size() &&
                  s.curtains_closed.size() == world.windows.size())
        << "world state does not belong to world " << world.name;
    // Rebuild only what the change touches (the bytes rendered are the same as after a
    // full rebuild): obstacles and textures -> segments and grid; lights -> light grid
    // and the baked planes (only the boxes of the zones switched); curtains are read at
    // draw time.
    const bool geometry_same = built && s.obstacle_offset_m == state.obstacle_offset_m &&
                               s.texture_seed == state.texture_seed && s.cleared == state.cleared &&
                               s.present == state.present;
    std::vector<int> zones_switched;
    for (std::size_t z = 0; z < world.lights.size(); ++z) {
      if (!built || s.light_on[z] != state.light_on[z] || s.light_scale[z] != state.light_scale[z])
        zones_switched.push_back(static_cast<int>(z));
    }
    state = s;
    if (!geometry_same) BuildGeometry(s);
    if (!built) {
      BuildLights();
      BakeFloor();
    } else if (!zones_switched.empty()) {
      BuildLights();
      RebakeZones(zones_switched);
    }
    built = true;
  }

  void BuildGeometry(const WorldState& s) {
    // Textures.
    textures.clear();
    for (std::size_t i = 0; i < world.obstacles.size(); ++i) {
      RuntimeTexture t;
      t.spec = world.obstacles[i].texture;
      t.spec.seed = s.texture_seed[i];
      t.base = ToRgb(t.spec.color_rgb);
      t.cleared = s.cleared[i] != 0;
      textures.push_back(t);
    }
    // Segments.
    segments.clear();
    for (std::size_t i = 0; i < world.obstacles.size(); ++i) {
      const Obstacle& o = world.obstacles[i];
      if (!s.present[i]) continue;  // taken away (layout changes)
      const auto pts = ObstacleOutline(world, s, static_cast<int>(i));
      const std::size_t n = o.closed ? pts.size() : pts.size() - 1;
      double u = 0;
      for (std::size_t k = 0; k < n; ++k) {
        Segment seg;
        seg.a = pts[k];
        seg.b = pts[(k + 1) % pts.size()];
        seg.length = (seg.b - seg.a).norm();
        if (seg.length < 1e-9) continue;
        seg.z0 = 0;
        seg.z1 = o.height_m;
        seg.u0 = u;
        u += seg.length;
        const Eigen::Vector2d normal =
            Eigen::Vector2d(-(seg.b - seg.a).y(), (seg.b - seg.a).x()) / seg.length;
        seg.face_shade =
            static_cast<float>(0.72 + 0.28 * std::abs(normal.dot(Eigen::Vector2d(0.6, 0.8))));
        seg.texture = static_cast<int>(i);
        segments.push_back(seg);
      }
    }
    for (std::size_t i = 0; i < world.windows.size(); ++i) {
      const WindowSpec& w = world.windows[i];
      Segment seg;
      seg.a = w.from_m;
      seg.b = w.to_m;
      seg.length = (seg.b - seg.a).norm();
      if (seg.length < 1e-9) continue;
      seg.z0 = w.bottom_m;
      seg.z1 = w.top_m;
      seg.window = static_cast<int>(i);
      segments.push_back(seg);
    }
    // Uniform grid (CSR). A segment goes into every cell its (slightly padded) box meets
    // and that it crosses (Liang-Barsky clip against the padded cell).
    grid_w = std::max(1, static_cast<int>(std::ceil(world.size_m.x() / kGridCellM)));
    grid_h = std::max(1, static_cast<int>(std::ceil(world.size_m.y() / kGridCellM)));
    std::vector<std::vector<int>> cells(static_cast<std::size_t>(grid_w) * grid_h);
    constexpr double kPad = 1e-6;
    for (std::size_t si = 0; si < segments.size(); ++si) {
      const Segment& seg = segments[si];
      const int x0 = std::clamp(
          static_cast<int>(std::floor((std::min(seg.a.x(), seg.b.x()) - kPad) / kGridCellM)), 0,
          grid_w - 1);
      const int x1 = std::clamp(
          static_cast<int>(std::floor((std::max(seg.a.x(), seg.b.x()) + kPad) / kGridCellM)), 0,
          grid_w - 1);
      const int y0 = std::clamp(
          static_cast<int>(std::floor((std::min(seg.a.y(), seg.b.y()) - kPad) / kGridCellM)), 0,
          grid_h - 1);
      const int y1 = std::clamp(
          static_cast<int>(std::floor((std::max(seg.a.y(), seg.b.y()) + kPad) / kGridCellM)), 0,
          grid_h - 1);
      for (int cy = y0; cy <= y1; ++cy) {
        for (int cx = x0; cx <= x1; ++cx) {
          const double bx0 = cx * kGridCellM - kPad, bx1 = (cx + 1) * kGridCellM + kPad;
          const double by0 = cy * kGridCellM - kPad, by1 = (cy + 1) * kGridCellM + kPad;
          // Cells on the grid border extend to infinity so nothing is lost outside.
          const double ex0 = cx == 0 ? -1e18 : bx0, ex1 = cx == grid_w - 1 ? 1e18 : bx1;
          const double ey0 = cy == 0 ? -1e18 : by0, ey1 = cy == grid_h - 1 ? 1e18 : by1;
          double t0 = 0, t1 = 1;
          const Eigen::Vector2d d = seg.b - seg.a;
          bool inside = true;
          const double p[4] = {-d.x(), d.x(), -d.y(), d.y()};
          const double q[4] = {seg.a.x() - ex0, ex1 - seg.a.x(), seg.a.y() - ey0, ey1 - seg.a.y()};
          for (int k = 0; k < 4 && inside; ++k) {
            if (p[k] == 0) {
              if (q[k] < 0) inside = false;
            } else {
              const double r = q[k] / p[k];
              if (p[k] < 0)
                t0 = std::max(t0, r);
              else
                t1 = std::min(t1, r);
              if (t0 > t1) inside = false;
            }
          }
          if (inside)
            cells[static_cast<std::size_t>(cy) * grid_w + cx].push_back(static_cast<int>(si));
        }
      }
    }
    cell_start.assign(cells.size() + 1, 0);
    cell_segs.clear();
    for (std::size_t i = 0; i < cells.size(); ++i) {
      cell_start[i] = static_cast<int>(cell_segs.size());
      cell_segs.insert(cell_segs.end(), cells[i].begin(), cells[i].end());
    }
    cell_start[cells.size()] = static_cast<int>(cell_segs.size());
  }

  // The lit ceiling at (x, y): lamps switched on are bright panels, off ones grey.
  Rgb CeilingColor(double x, double y) const {
    const std::size_t li = LightIndex(x, y);
    if (lamp[li] == 2) return {255, 252, 240};
    if (lamp[li] == 1) return {105, 105, 112};
    return Scale(SampleTexture(ceiling_tex, x, y), light[li]);
  }

  void Bake(double cell_m, BakedPlanes* planes) const {
    planes->cell_m = cell_m;
    planes->w = std::max(1, static_cast<int>(std::ceil(world.size_m.x() / cell_m)));
    planes->h = std::max(1, static_cast<int>(std::ceil(world.size_m.y() / cell_m)));
    planes->floor_bgr.resize(static_cast<std::size_t>(planes->w) * planes->h * 3);
    planes->ceiling_bgr.resize(planes->floor_bgr.size());
    BakeCells(0, planes->w - 1, 0, planes->h - 1, planes);
  }

  // (Re)bakes the cells [cx0, cx1] x [cy0, cy1] of `planes` from the current lights.
  void BakeCells(int cx0, int cx1, int cy0, int cy1, BakedPlanes* planes) const {
    const double cell_m = planes->cell_m;
    for (int cy = cy0; cy <= cy1; ++cy) {
      const double y = (cy + 0.5) * cell_m;
      std::uint8_t* out = planes->floor_bgr.data() + static_cast<std::size_t>(cy) * planes->w * 3;
      std::uint8_t* top = planes->ceiling_bgr.data() + static_cast<std::size_t>(cy) * planes->w * 3;
      for (int cx = cx0; cx <= cx1; ++cx) {
        const double x = (cx + 0.5) * cell_m;
        const Rgb c = Scale(SampleTexture(floor_tex, x, y), light[LightIndex(x, y)]);
        out[3 * cx] = Sat(c.b);
        out[3 * cx + 1] = Sat(c.g);
        out[3 * cx + 2] = Sat(c.r);
        const Rgb t = CeilingColor(x, y);
        top[3 * cx] = Sat(t.b);
        top[3 * cx + 1] = Sat(t.g);
        top[3 * cx + 2] = Sat(t.r);
      }
    }
  }

  // Light-grid cells [*cx0, *cx1] x [*cy0, *cy1] covering zone z's bounding box (the only
  // cells whose light or lamp the zone sets; BuildLights visits the same box).
  void ZoneLightBox(int z, int* cx0, int* cx1, int* cy0, int* cy1) const {
    double xmin = 1e18, xmax = -1e18, ymin = 1e18, ymax = -1e18;
    for (const auto& p : world.lights[z].polygon_m) {
      xmin = std::min(xmin, p.x());
      xmax = std::max(xmax, p.x());
      ymin = std::min(ymin, p.y());
      ymax = std::max(ymax, p.y());
    }
    *cx0 = std::clamp(static_cast<int>(std::floor(xmin / kLightCellM)), 0, light_w - 1);
    *cx1 = std::clamp(static_cast<int>(std::ceil(xmax / kLightCellM)), 0, light_w - 1);
    *cy0 = std::clamp(static_cast<int>(std::floor(ymin / kLightCellM)), 0, light_h - 1);
    *cy1 = std::clamp(static_cast<int>(std::ceil(ymax / kLightCellM)), 0, light_h - 1);
  }

  // After BuildLights for switched zones: rebakes the baked-plane cells whose light cell
  // lies in a switched zone's box (padded by one baked cell; cells past the light grid's
  // last row or column, which LightIndex clamps onto it, included).
  void RebakeZones(const std::vector<int>& zones) {
    for (BakedPlanes* planes : {&fine, &coarse}) {
      for (int z : zones) {
        int lx0, lx1, ly0, ly1;
        ZoneLightBox(z, &lx0, &lx1, &ly0, &ly1);
        const auto lo = [&](int l, int n) {
          return l == 0 ? 0
                        : std::clamp(
                              static_cast<int>(std::floor(l * kLightCellM / planes->cell_m)) - 1, 0,
                              n - 1);
        };
        const auto hi = [&](int l, int lmax, int n) {
          return l == lmax
                     ? n - 1
                     : std::clamp(
                           static_cast<int>(std::ceil((l + 1) * kLightCellM / planes->cell_m)) + 1,
                           0, n - 1);
        };
        BakeCells(lo(lx0, planes->w), hi(lx1, light_w - 1, planes->w), lo(ly0, planes->h),
                  hi(ly1, light_h - 1, planes->h), planes);
      }
    }
  }

  void BakeFloor() {
    // At most ~2 M fine cells (store_large: 4.5 cm cells).
    const double area = world.size_m.x() * world.size_m.y();
    const double cell = std::max(0.025, std::sqrt(area / 2.0e6));
    Bake(cell, &fine);
    Bake(4 * cell, &coarse);
    const double pixel_rad = std::min(kTwoPi / width, elev_step);
    row_coarse.resize(height);
    for (int r = 0; r < height; ++r)
      row_coarse[r] = row_plane_dist[r] * pixel_rad > 0.5 * coarse.cell_m;
  }

  void BuildLights() {
    light_w = std::max(1, static_cast<int>(std::ceil(world.size_m.x() / kLightCellM)));
    light_h = std::max(1, static_cast<int>(std::ceil(world.size_m.y() / kLightCellM)));
    light.assign(static_cast<std::size_t>(light_w) * light_h,
                 static_cast<float>(world.ambient_light));
    lamp.assign(light.size(), 0);
    for (std::size_t z = 0; z < world.lights.size(); ++z) {
      const LightZone& zone = world.lights[z];
      const bool on = state.light_on[z] != 0;
      double xmin = 1e18, xmax = -1e18, ymin = 1e18, ymax = -1e18;
      for (const auto& p : zone.polygon_m) {
        xmin = std::min(xmin, p.x());
        xmax = std::max(xmax, p.x());
        ymin = std::min(ymin, p.y());
        ymax = std::max(ymax, p.y());
      }
      const int cx0 = std::clamp(static_cast<int>(std::floor(xmin / kLightCellM)), 0, light_w - 1);
      const int cx1 = std::clamp(static_cast<int>(std::ceil(xmax / kLightCellM)), 0, light_w - 1);
      const int cy0 = std::clamp(static_cast<int>(std::floor(ymin / kLightCellM)), 0, light_h - 1);
      const int cy1 = std::clamp(static_cast<int>(std::ceil(ymax / kLightCellM)), 0, light_h - 1);
      const double sp = zone.lamp_spacing_m;
      for (int cy = cy0; cy <= cy1; ++cy) {
        for (int cx = cx0; cx <= cx1; ++cx) {
          const Eigen::Vector2d p((cx + 0.5) * kLightCellM, (cy + 0.5) * kLightCellM);
          if (!geometry::PointInPolygon(zone.polygon_m, p)) continue;
          const std::size_t idx = static_cast<std::size_t>(cy) * light_w + cx;
          if (on) light[idx] += static_cast<float>(zone.intensity * state.light_scale[z]);
          // Lamps: 0.6 m x 0.3 m panels centred on the zone's lamp grid.
          const double gx = (p.x() - xmin) / sp, gy = (p.y() - ymin) / sp;
          const double fx = gx - std::floor(gx) - 0.5, fy = gy - std::floor(gy) - 0.5;
          if (std::abs(fx * sp) < 0.3 && std::abs(fy * sp) < 0.15) lamp[idx] = on ? 2 : 1;
        }
      }
    }
  }

  inline std::size_t LightIndex(double x, double y) const {
    const int cx = std::clamp(static_cast<int>(x * (1.0 / kLightCellM)), 0, light_w - 1);
    const int cy = std::clamp(static_cast<int>(y * (1.0 / kLightCellM)), 0, light_h - 1);
    return static_cast<std::size_t>(cy) * light_w + cx;
  }

  // Rows whose centre elevation lies within [atan(lo), atan(hi)] (tangents), as [first, last].
  inline void RowRange(double tan_lo, double tan_hi, int* first, int* last) const {
    // row_neg_tan increases with r: rows with -tan in [-hi, -lo].
    *first = static_cast<int>(std::lower_bound(row_neg_tan.begin(), row_neg_tan.end(), -tan_hi) -
                              row_neg_tan.begin());
    *last = static_cast<int>(std::upper_bound(row_neg_tan.begin(), row_neg_tan.end(), -tan_lo) -
                             row_neg_tan.begin()) -
            1;
  }

  // Fills the unfilled rows of column `col` covered by `hit`.
  void DrawHit(const Hit& hit, const Eigen::Vector2d& cam, const Eigen::Vector2d& dir,
               const std::vector<Person>& people, ColumnState* cs, cv::Mat* pano, int col) const {
    double z0, z1;
    const Segment* seg = hit.segment >= 0 ? &segments[hit.segment] : nullptr;
    if (seg) {
      z0 = seg->z0;
      z1 = seg->z1;
    } else {
      z0 = 0;
      z1 = people[hit.person].height_m;
    }
    int first, last;
    RowRange((z0 - cam_h) / hit.t, (z1 - cam_h) / hit.t, &first, &last);
    first = std::max(first, cs->lo);
    last = std::min(last, cs->hi);
    if (first > last) return;
    std::uint8_t* column_filled = cs->filled;
    // Light: just in front of the surface, on the camera's side.
    const Eigen::Vector2d lp = hit.point - 0.05 * dir;
    float shade = light[LightIndex(lp.x(), lp.y())];
    (void)cam;
    if (seg && seg->window < 0) {
      // Obstacle face: the sampler gives runs of equal colours down a column (texture
      // cells), so shading and rounding are redone only when its colour changes.
      ColumnSampler sampler(textures[seg->texture], hit.u);
      const float s = shade * seg->face_shade;
      Rgb last_in{};
      bool have_last = false;
      std::uint8_t b = 0, g = 0, red = 0;
      for (int r = first; r <= last; ++r) {
        if (column_filled[r]) continue;
        column_filled[r] = 1;
        const Rgb in = sampler(cam_h + hit.t * row_tan[r]);
        if (!have_last || in.r != last_in.r || in.g != last_in.g || in.b != last_in.b) {
          const Rgb c = Scale(in, s);
          b = Sat(c.b);
          g = Sat(c.g);
          red = Sat(c.r);
          last_in = in;
          have_last = true;
        }
        std::uint8_t* px = pano->ptr<std::uint8_t>(r) + 3 * col;
        px[0] = b;
        px[1] = g;
        px[2] = red;
      }
      while (cs->lo <= cs->hi && column_filled[cs->lo]) ++cs->lo;
      while (cs->hi >= cs->lo && column_filled[cs->hi]) --cs->hi;
      return;
    }
    for (int r = first; r <= last; ++r) {
      if (column_filled[r]) continue;
      column_filled[r] = 1;
      const double z = cam_h + hit.t * row_tan[r];
      Rgb c;
      if (seg) {
        const WindowSpec& w = world.windows[seg->window];
        const double fu = hit.u / seg->length;
        const double fz = (z - w.bottom_m) / (w.top_m - w.bottom_m);
        const bool frame = fu < 0.03 || fu > 0.97 || std::abs(fu - 0.5) < 0.015 || fz < 0.04 ||
                           fz > 0.96 || std::abs(fz - 0.55) < 0.02;
        if (frame) {
          c = Scale(Rgb{225, 225, 220}, shade);
        } else if (state.curtains_closed[seg->window]) {
          const float fold = 0.78f + 0.22f * static_cast<float>(std::sin(kTwoPi * hit.u / 0.14));
          c = Scale(ToRgb(w.curtain_rgb), shade * fold);
        } else {
          // Daylight, brighter towards the top; not lit by the room.
          c = Scale(ToRgb(w.outside_rgb), static_cast<float>(0.85 + 0.15 * fz));
        }
      } else {
        const Person& p = people[hit.person];
        const double rel = z / p.height_m;
        const std::uint64_t h = Hash(p.seed, 1, 2);
        if (rel > 0.87) {
          c = {205, 160, 130};  // head
        } else if (rel > 0.48) {
          c = Palette()[h & 63];  // shirt
        } else {
          c = Scale(Palette()[(h >> 8) & 63], 0.45f);  // trousers
        }
        c = Scale(c, shade);
      }
      std::uint8_t* px = pano->ptr<std::uint8_t>(r) + 3 * col;
      px[0] = Sat(c.b);
      px[1] = Sat(c.g);
      px[2] = Sat(c.r);
    }
    while (cs->lo <= cs->hi && column_filled[cs->lo]) ++cs->lo;
    while (cs->hi >= cs->lo && column_filled[cs->hi]) --cs->hi;
  }

  // Draws the surfaces column `col` (ray along dir) sees and marks the rows they leave
  // open in open_mask (row-major, width x height) for FillPlanes.
  void RenderColumn(int col, const Eigen::Vector2d& dir, const Eigen::Vector2d& cam,
                    const std::vector<Person>& people, cv::Mat* pano, std::vector<Hit>* cell_hits,
                    std::vector<Hit>* people_hits, std::uint8_t* filled,
                    std::uint8_t* open_mask) const {
    std::fill(filled, filled + height, 0);
    ColumnState cs{filled, 0, height - 1};
    // People: ray-cylinder hits.
    people_hits->clear();
    for (std::size_t i = 0; i < people.size(); ++i) {
      const Eigen::Vector2d f = cam - people[i].position_m;
      const double b = f.dot(dir);
      const double c = f.squaredNorm() - people[i].radius_m * people[i].radius_m;
      if (c <= 0) continue;  // camera inside the person: not drawn
      const double disc = b * b - c;
      if (disc < 0) continue;
      const double t = -b - std::sqrt(disc);
      if (t <= 1e-6) continue;
      people_hits->push_back({t, 0.0, -1, static_cast<int>(i), cam + t * dir});
    }
    std::sort(people_hits->begin(), people_hits->end(),
              [](const Hit& a, const Hit& b) { return a.t < b.t; });
    std::size_t next_person = 0;

    // Amanatides-Woo traversal of the segment grid.
    int cx = std::clamp(static_cast<int>(std::floor(cam.x() / kGridCellM)), 0, grid_w - 1);
    int cy = std::clamp(static_cast<int>(std::floor(cam.y() / kGridCellM)), 0, grid_h - 1);
    const int step_x = dir.x() > 0 ? 1 : -1;
    const int step_y = dir.y() > 0 ? 1 : -1;
    const double inf = std::numeric_limits<double>::infinity();
    const double tdx = dir.x() != 0 ? kGridCellM / std::abs(dir.x()) : inf;
    const double tdy = dir.y() != 0 ? kGridCellM / std::abs(dir.y()) : inf;
    // (max with 0: a camera exactly on a cell border gives -0 here.)
    double tmx = dir.x() != 0
                     ? std::max(0.0, ((cx + (step_x > 0 ? 1 : 0)) * kGridCellM - cam.x()) / dir.x())
                     : inf;
    double tmy = dir.y() != 0
                     ? std::max(0.0, ((cy + (step_y > 0 ? 1 : 0)) * kGridCellM - cam.y()) / dir.y())
                     : inf;
    // Border cells extend to infinity (see Build): leaving the grid ends the ray. A ray
    // through a cell corner (tmx == tmy) crosses both borders at once; it leaves the grid
    // if either step does (the step below is along y at a tie, which must stay inside).
    double t_enter = 0;
    while (true) {
      double t_exit = std::min(tmx, tmy);
      const bool leaves_x = tmx <= tmy && (cx + step_x < 0 || cx + step_x >= grid_w);
      const bool leaves_y = tmy <= tmx && (cy + step_y < 0 || cy + step_y >= grid_h);
      const bool last_cell = leaves_x || leaves_y || t_exit > max_range;
      if (last_cell) t_exit = inf;
      cell_hits->clear();
      const std::size_t cell = static_cast<std::size_t>(cy) * grid_w + cx;
      for (int k = cell_start[cell]; k < cell_start[cell + 1]; ++k) {
        const int si = cell_segs[k];
        const Segment& s = segments[si];
        const Eigen::Vector2d e = s.b - s.a;
        const double denom = dir.x() * e.y() - dir.y() * e.x();
        if (std::abs(denom) < 1e-12) continue;
        const Eigen::Vector2d ap = s.a - cam;
        const double t = (ap.x() * e.y() - ap.y() * e.x()) / denom;
        if (t < t_enter || t >= t_exit || t <= 1e-6) continue;
        const double sp = (ap.x() * dir.y() - ap.y() * dir.x()) / denom;
        if (sp < 0 || sp > 1) continue;
        const double t_draw = s.window >= 0 ? t - kWindowNudgeM : t;
        cell_hits->push_back({t_draw, s.u0 + sp * s.length, si, -1, cam + t * dir});
      }
      while (next_person < people_hits->size() && (*people_hits)[next_person].t < t_exit) {
        cell_hits->push_back((*people_hits)[next_person++]);
      }
      if (!cell_hits->empty()) {
        // Insertion sort: a cell holds few hits.
        for (std::size_t i = 1; i < cell_hits->size(); ++i) {
          const Hit h = (*cell_hits)[i];
          std::size_t j = i;
          while (j > 0 &&
                 ((*cell_hits)[j - 1].t > h.t ||
                  ((*cell_hits)[j - 1].t == h.t && (*cell_hits)[j - 1].segment > h.segment))) {
            (*cell_hits)[j] = (*cell_hits)[j - 1];
            --j;
          }
          (*cell_hits)[j] = h;
        }
        for (const Hit& h : *cell_hits) DrawHit(h, cam, dir, people, &cs, pano, col);
      }
      if (last_cell || cs.lo > cs.hi) break;
      // Can anything farther than t_exit still fill an empty row?
      int first = 0, last = height - 1;
      if (t_exit > 1e-6) RowRange(-cam_h / t_exit, (max_height - cam_h) / t_exit, &first, &last);
      bool open = false;
      for (int r = std::max(first, cs.lo); r <= std::min(last, cs.hi); ++r) {
        if (!filled[r]) {
          open = true;
          break;
        }
      }
      if (!open) break;
      t_enter = t_exit;
      if (tmx < tmy) {
        cx += step_x;
        tmx += tdx;
      } else {
        cy += step_y;
        tmy += tdy;
      }
    }
    // The rows no surface filled get the floor or the ceiling in FillPlanes, row by row.
    std::uint8_t* open_rows = open_mask + col;
    for (int r = 0; r < height; ++r) open_rows[static_cast<std::size_t>(r) * width] = !filled[r];
  }

  // Floor and ceiling in the pixels open_mask marks (row-major, 1 = no surface), rays
  // along dirs (one per column). Row by row: the points of one row lie on a circle
  // around the camera, neighbours a fraction of a baked cell apart, so the baked rasters
  // are read with locality (column by column they were read far apart, one cache miss
  // per pixel). Same bytes as a column-by-column fill.
  void FillPlanes(const Eigen::Vector2d& cam, const std::vector<Eigen::Vector2d>& dirs,
                  const std::uint8_t* open_mask, cv::Mat* pano) const {
    for (int r = 0; r < height; ++r) {
      const std::uint8_t* open = open_mask + static_cast<std::size_t>(r) * width;
      std::uint8_t* row = pano->ptr<std::uint8_t>(r);
      const double d = row_plane_dist[r];
      const bool finite = std::isfinite(d);
      const BakedPlanes& planes = row_coarse[r] ? coarse : fine;
      const std::uint8_t* raster =
          row_tan[r] < 0 ? planes.floor_bgr.data() : planes.ceiling_bgr.data();
      for (int col = 0; col < width; ++col) {
        if (!open[col]) continue;
        std::uint8_t* px = row + 3 * col;
        const Eigen::Vector2d& dir = dirs[col];
        if (finite) {
          // Floor or ceiling: from the baked rasters when inside the floor plan.
          const Eigen::Vector2d p = cam + d * dir;
          const double fx = p.x() / planes.cell_m, fy = p.y() / planes.cell_m;
          if (fx >= 0 && fy >= 0 && fx < planes.w && fy < planes.h) {
            const std::uint8_t* src =
                raster +
                (static_cast<std::size_t>(fy) * planes.w + static_cast<std::size_t>(fx)) * 3;
            px[0] = src[0];
            px[1] = src[1];
            px[2] = src[2];
            continue;
          }
        }
        Rgb c;
        if (!finite) {
          c = {60, 60, 60};
        } else {
          const Eigen::Vector2d p = cam + d * dir;
          const std::size_t li = LightIndex(p.x(), p.y());
          if (row_tan[r] < 0) {
            c = Scale(SampleTexture(floor_tex, p.x(), p.y()), light[li]);
          } else {
            c = CeilingColor(p.x(), p.y());
          }
        }
        px[0] = Sat(c.b);
        px[1] = Sat(c.g);
        px[2] = Sat(c.r);
      }
    }
  }
};

Renderer::Renderer(const World& world, std::uint64_t noise_seed)
    : impl_(std::make_unique<Impl>(world, noise_seed)) {
  impl_->Build(InitialWorldState(world));
}
Renderer::~Renderer() = default;

void Renderer::SetState(const WorldState& state) { impl_->Build(state); }
const WorldState& Renderer::state() const { return impl_->state; }
const World& Renderer::world() const { return impl_->world; }
const OmniUnwrapper& Renderer::unwrapper() const { return impl_->unwrapper; }
double Renderer::RowElevationRad(int row) const {
  return impl_->elev_max - (row + 0.5) * impl_->elev_step;
}

cv::Mat Renderer::RenderPanorama(const Pose2& map_T_robot,
                                 const std::vector<Person>& people) const {
  cv::Mat pano;
  RenderPanorama(map_T_robot, people, &pano);
  return pano;
}

void Renderer::RenderPanorama(const Pose2& map_T_robot, const std::vector<Person>& people,
                              cv::Mat* pano) const {
  OMNICML_CHECK(pano != nullptr);
  const Impl& m = *impl_;
  pano->create(m.height, m.width, CV_8UC3);
  // Heading in columns. When it is (within 1e-6 columns of) an integer k, column c's ray
  // is computed from the integer (k + c) mod W, so a turn by whole columns rolls the
  // panorama exactly (omni_unwrapper.h convention).
  double h_cols = map_T_robot.z() * m.width / kTwoPi;
  if (std::abs(h_cols - std::round(h_cols)) < 1e-6) h_cols = std::round(h_cols);
  const double h_floor = std::floor(h_cols);
  const double h_frac = h_cols - h_floor;
  const std::int64_t h_int = static_cast<std::int64_t>(h_floor);
  const Eigen::Vector2d cam = map_T_robot.head<2>();
  std::vector<Hit> cell_hits, people_hits;
  cell_hits.reserve(64);
  std::vector<std::uint8_t> filled(m.height);
  std::vector<std::uint8_t> open_mask(static_cast<std::size_t>(m.width) * m.height);
  std::vector<Eigen::Vector2d> dirs(m.width);
  for (int c = 0; c < m.width; ++c) {
    const std::int64_t idx = ((h_int + c) % m.width + m.width) % m.width;
    const double theta = kTwoPi * (static_cast<double>(idx) + h_frac) / m.width;
    dirs[c] = Eigen::Vector2d(std::cos(theta), std::sin(theta));
    m.RenderColumn(c, dirs[c], cam, people, pano, &cell_hits, &people_hits, filled.data(),
                   open_mask.data());
  }
  m.FillPlanes(cam, dirs, open_mask.data(), pano);
}

cv::Mat Renderer::RenderRing(const cv::Mat& panorama) const {
  return impl_->unwrapper.Render(panorama);
}

void Renderer::AddSensorNoise(cv::Mat* image, std::uint64_t frame_seed) const {
  OMNICML_CHECK(image != nullptr && image->depth() == CV_8U);
  const Impl& m = *impl_;
  if (m.world.camera.noise_sigma_gray <= 0) return;
  const std::size_t row_bytes = static_cast<std::size_t>(image->cols) * image->channels();
  const std::size_t total = row_bytes * image->rows;
  OMNICML_CHECK(total + m.noise_period <= m.noise_table.size())
      << "image larger than the noise table";
  const std::size_t offset = MixSeed(frame_seed, 0x0FF5ULL) % m.noise_period;
  const std::int8_t* noise = m.noise_table.data() + offset;
  for (int r = 0; r < image->rows; ++r) {
    std::uint8_t* p = image->ptr<std::uint8_t>(r);
    const std::int8_t* n = noise + static_cast<std::size_t>(r) * row_bytes;
    std::size_t i = 0;
#if defined(__SSE2__)
    // sat(p + n) = ((p - 128) +sat n) + 128 with signed saturating bytes; same result as
    // the scalar loop below.
    const __m128i bias = _mm_set1_epi8(static_cast<char>(0x80));
    for (; i + 16 <= row_bytes; i += 16) {
      const __m128i pv =
          _mm_xor_si128(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p + i)), bias);
      const __m128i nv = _mm_loadu_si128(reinterpret_cast<const __m128i*>(n + i));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(p + i),
                       _mm_xor_si128(_mm_adds_epi8(pv, nv), bias));
    }
#endif
    for (; i < row_bytes; ++i) {
      const int v = p[i] + n[i];
      p[i] = static_cast<std::uint8_t>(v < 0 ? 0 : v > 255 ? 255 : v);
    }
  }
}

cv::Mat DrawFloorPlan(const World& world, const WorldState& state,
                      const std::vector<Eigen::Vector2d>& path_m, const std::vector<Pose2>& poses,
                      double px_per_m) {
  OMNICML_CHECK(px_per_m > 0);
  const int margin = 10;
  const int w = static_cast<int>(std::ceil(world.size_m.x() * px_per_m)) + 2 * margin;
  const int h = static_cast<int>(std::ceil(world.size_m.y() * px_per_m)) + 2 * margin;
  cv::Mat img(h, w, CV_8UC3, cv::Scalar(250, 250, 250));
  const auto to_px = [&](const Eigen::Vector2d& p) {
    return cv::Point(static_cast<int>(std::lround(margin + p.x() * px_per_m)),
                     static_cast<int>(std::lround(h - margin - p.y() * px_per_m)));
  };
  for (std::size_t z = 0; z < world.lights.size(); ++z) {
    std::vector<cv::Point> poly;
    for (const auto& p : world.lights[z].polygon_m) poly.push_back(to_px(p));
    if (state.light_on[z])
      cv::fillPoly(img, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(200, 245, 255));
    cv::polylines(img, poly, true, cv::Scalar(120, 200, 230), 1);
  }
  for (std::size_t i = 0; i < world.obstacles.size(); ++i) {
    const Obstacle& o = world.obstacles[i];
    if (!state.present[i]) continue;
    std::vector<cv::Point> poly;
    for (const auto& p : ObstacleOutline(world, state, static_cast<int>(i)))
      poly.push_back(to_px(p));
    if (o.closed && o.kind != ObstacleKind::kWall) {
      const cv::Scalar fill =
          o.kind == ObstacleKind::kShelf
              ? (state.cleared[i] ? cv::Scalar(200, 200, 200) : cv::Scalar(150, 110, 70))
              : cv::Scalar(90, 140, 190);
      cv::fillPoly(img, std::vector<std::vector<cv::Point>>{poly}, fill);
    }
    cv::polylines(img, poly, o.closed, cv::Scalar(40, 40, 40),
                  o.kind == ObstacleKind::kWall ? 2 : 1);
  }
  for (std::size_t i = 0; i < world.windows.size(); ++i) {
    cv::line(img, to_px(world.windows[i].from_m), to_px(world.windows[i].to_m),
             state.curtains_closed[i] ? cv::Scalar(60, 60, 180) : cv::Scalar(255, 200, 80), 3);
  }
  if (path_m.size() >= 2) {
    std::vector<cv::Point> line;
    for (const auto& p : path_m) line.push_back(to_px(p));
    cv::polylines(img, line, false, cv::Scalar(0, 160, 0), 1, cv::LINE_AA);
  }
  for (const auto& p : poses) {
    const cv::Point a = to_px(p.head<2>());
    const Eigen::Vector2d tip =
        p.head<2>() + 0.8 * Eigen::Vector2d(std::cos(p.z()), std::sin(p.z()));
    cv::arrowedLine(img, a, to_px(tip), cv::Scalar(0, 0, 220), 2, cv::LINE_AA, 0, 0.4);
  }
  return img;
}

}  // namespace omnicml
