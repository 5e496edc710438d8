#include "omnicml/unwrap/auto_calibration.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"
#include "unwrap/internal/circle_fit.h"

namespace omnicml {
namespace {

// Gradient of a smoothed grey copy of a frame at some scale, with the frame's edge
// strength threshold.
struct Gradients {
  cv::Mat gx, gy;          // CV_32F, grey levels per pixel
  double threshold = 0.0;  // minimum radial gradient of an edge sample
  double scale = 1.0;      // this image's pixels per full-resolution pixel
};

Gradients MakeGradients(const cv::Mat& raw, double scale) {
  cv::Mat grey;
  if (raw.channels() == 3) {
    cv::cvtColor(raw, grey, cv::COLOR_BGR2GRAY);
  } else {
    grey = raw;
  }
  cv::Mat small;
  if (scale < 1.0) {
    cv::resize(grey, small, cv::Size(), scale, scale, cv::INTER_AREA);
  } else {
    small = grey;
  }
  cv::Mat f;
  small.convertTo(f, CV_32F);
  cv::GaussianBlur(f, f, cv::Size(0, 0), 1.0);
  Gradients g;
  g.scale = scale;
  cv::Sobel(f, g.gx, CV_32F, 1, 0, 3, 1.0 / 8.0);
  cv::Sobel(f, g.gy, CV_32F, 0, 1, 3, 1.0 / 8.0);
  // Threshold: the 80th percentile of the gradient magnitude (most of a scene is smoother
  // than its strongest edges), at least 2 grey levels per pixel.
  cv::Mat magnitude;
  cv::magnitude(g.gx, g.gy, magnitude);
  std::vector<float> values(magnitude.begin<float>(), magnitude.end<float>());
  const auto k = values.begin() + static_cast<std::ptrdiff_t>(0.8 * (values.size() - 1));
  std::nth_element(values.begin(), k, values.end());
  g.threshold = std::max(2.0, static_cast<double>(*k));
  return g;
}

// Strength of a radial edge at (x, y) along direction (cs, sn): |radial gradient| when it
// is above the threshold and the gradient points along the ray (within ~34 degrees),
// else 0. Nearest-neighbour when `bilinear` is false.
float RadialStrength(const Gradients& g, double x, double y, double cs, double sn, bool bilinear) {
  float gx, gy;
  if (bilinear) {
    const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
    if (x0 < 0 || y0 < 0 || x0 + 1 >= g.gx.cols || y0 + 1 >= g.gx.rows) return 0.0f;
    const float ax = static_cast<float>(x - x0), ay = static_cast<float>(y - y0);
    const auto lerp = [&](const cv::Mat& m) {
      const float* r0 = m.ptr<float>(y0);
      const float* r1 = m.ptr<float>(y0 + 1);
      return (1 - ay) * ((1 - ax) * r0[x0] + ax * r0[x0 + 1]) +
             ay * ((1 - ax) * r1[x0] + ax * r1[x0 + 1]);
    };
    gx = lerp(g.gx);
    gy = lerp(g.gy);
  } else {
    const int xi = static_cast<int>(std::lround(x)), yi = static_cast<int>(std::lround(y));
    if (xi < 0 || yi < 0 || xi >= g.gx.cols || yi >= g.gx.rows) return 0.0f;
    gx = g.gx.at<float>(yi, xi);
    gy = g.gy.at<float>(yi, xi);
  }
  const float radial = std::fabs(static_cast<float>(gx * cs + gy * sn));
  const float tangential = std::fabs(static_cast<float>(-gx * sn + gy * cs));
  if (radial < g.threshold || radial < 1.5f * tangential) return 0.0f;
  return radial;
}

// Support counts of circles around one centre: for radius bin j (pixels of g),
// support[j] counts rays with an edge (a local maximum of the radial strength) within
// `tol` of j, visible[j] the rays whose point at j lies inside the image.
void AccumulateSupport(const Gradients& g, cv::Point2d c, int rays, int r_lo, int r_hi, int tol,
                       std::vector<int>& support, std::vector<int>& visible) {
  const int n = r_hi + tol + 2;
  std::vector<float> strength(static_cast<std::size_t>(n) + 1);
  std::vector<int> edge_prefix(static_cast<std::size_t>(n) + 2);
  for (int k = 0; k < rays; ++k) {
    const double a = kTwoPi * k / rays, cs = std::cos(a), sn = std::sin(a);
    int inside = 0;  // samples [0, inside) lie in the image
    for (int i = std::max(0, r_lo - tol - 1); i <= n; ++i) {
      const double x = c.x + i * cs, y = c.y + i * sn;
      if (x < 0 || y < 0 || x > g.gx.cols - 1 || y > g.gx.rows - 1) {
        strength[i] = 0.0f;
        continue;
      }
      inside = i + 1;
      strength[i] = RadialStrength(g, x, y, cs, sn, false);
    }
    // Prefix counts of local maxima.
    edge_prefix[0] = 0;
    for (int i = 0; i <= n; ++i) {
      const bool edge = i >= 1 && i < n && strength[i] > 0.0f && strength[i] >= strength[i - 1] &&
                        strength[i] >= strength[i + 1];
      edge_prefix[i + 1] = edge_prefix[i] + (edge ? 1 : 0);
    }
    for (int j = r_lo; j <= r_hi; ++j) {
      if (j >= inside) break;
      ++visible[j];
      const int lo = std::max(0, j - tol), hi = std::min(n, j + tol);
      if (edge_prefix[hi + 1] - edge_prefix[lo] > 0) ++support[j];
    }
  }
}

struct Candidate {
  cv::Point2d center;  // in pixels of the gradient images searched
  double radius = 0;
  double score = -1;
};

// Best-supported circle over a grid of centres and radii [r_lo, r_hi] (pixels of the
// gradient images). Among circles about concentric with the best (centre within 10 % of
// its radius) whose support is within `prefer_outer` of the best, the largest wins (the
// rim encloses the robot's own body and its reflections).
Candidate SearchCircle(const std::vector<Gradients>& grads, const std::vector<cv::Point2d>& centres,
                       int rays, int r_lo, int r_hi, int tol, double prefer_outer) {
  const int bins = r_hi + 1;
  std::vector<Candidate> best_per_centre;
  for (const cv::Point2d& c : centres) {
    std::vector<int> support(static_cast<std::size_t>(bins), 0), visible(support);
    for (const Gradients& g : grads)
      AccumulateSupport(g, c, rays, r_lo, r_hi, tol, support, visible);
    const int min_visible = static_cast<int>(std::ceil(0.5 * rays * grads.size()));
    // Local maxima of the support over radius: candidate circles of this centre.
    for (int j = r_lo; j <= r_hi; ++j) {
      if (visible[j] < min_visible) continue;
      const double s = static_cast<double>(support[j]) / visible[j];
      const auto score_at = [&](int i) {
        return i < r_lo || i > r_hi || visible[i] < min_visible
                   ? -1.0
                   : static_cast<double>(support[i]) / visible[i];
      };
      if (s < score_at(j - 1) || s < score_at(j + 1)) continue;
      best_per_centre.push_back({c, static_cast<double>(j), s});
    }
  }
  Candidate best;
  for (const Candidate& cand : best_per_centre) {
    if (cand.score > best.score) best = cand;
  }
  if (best.score <= 0) return best;
  Candidate chosen = best;
  for (const Candidate& cand : best_per_centre) {
    const bool concentric = std::hypot(cand.center.x - best.center.x,
                                       cand.center.y - best.center.y) <= 0.1 * best.radius + tol;
    if (concentric && cand.score >= prefer_outer * best.score &&
        (cand.radius > chosen.radius + tol ||
         (std::abs(cand.radius - chosen.radius) <= tol && cand.score > chosen.score))) {
      chosen = cand;
    }
  }
  return chosen;
}

std::vector<cv::Point2d> Grid(cv::Point2d lo, cv::Point2d hi, double step) {
  std::vector<cv::Point2d> out;
  for (double y = lo.y; y <= hi.y + 1e-9; y += step) {
    for (double x = lo.x; x <= hi.x + 1e-9; x += step) out.emplace_back(x, y);
  }
  return out;
}

// One sub-pixel edge point per ray near radius `r` (full resolution): the strongest
// radial edge within [r - w, r + w]; rays whose point at r leaves the image count as not
// visible. Returns the points; *visible_rays counts the rays inside the image.
std::vector<cv::Point2d> EdgePoints(const Gradients& g, cv::Point2d c, double r, double w, int rays,
                                    int* visible_rays) {
  std::vector<cv::Point2d> points;
  const int n = static_cast<int>(std::ceil(2 * w)) + 1;
  std::vector<float> s(static_cast<std::size_t>(n) + 2);
  for (int k = 0; k < rays; ++k) {
    const double a = kTwoPi * k / rays, cs = std::cos(a), sn = std::sin(a);
    const double xr = c.x + r * cs, yr = c.y + r * sn;
    if (xr < 1 || yr < 1 || xr > g.gx.cols - 2 || yr > g.gx.rows - 2) continue;
    ++*visible_rays;
    const double t0 = r - w - 1.0;
    int best = -1;
    for (int i = 0; i < n + 2; ++i) {
      const double t = t0 + i;
      s[i] = t <= 0 ? 0.0f : RadialStrength(g, c.x + t * cs, c.y + t * sn, cs, sn, true);
    }
    for (int i = 1; i <= n; ++i) {
      if (s[i] > 0 && s[i] >= s[i - 1] && s[i] >= s[i + 1] && (best < 0 || s[i] > s[best]))
        best = i;
    }
    if (best < 0) continue;
    double offset = 0.0;
    const double denom = s[best - 1] - 2.0 * s[best] + s[best + 1];
    if (denom < 0.0) offset = std::clamp(0.5 * (s[best - 1] - s[best + 1]) / denom, -0.5, 0.5);
    const double t = t0 + best + offset;
    points.emplace_back(c.x + t * cs, c.y + t * sn);
  }
  return points;
}

bool CircleThrough(cv::Point2d a, cv::Point2d b, cv::Point2d c, cv::Point2d* centre, double* r) {
  const double d = 2.0 * (a.x * (b.y - c.y) + b.x * (c.y - a.y) + c.x * (a.y - b.y));
  if (std::abs(d) < 1e-9) return false;
  const double a2 = a.dot(a), b2 = b.dot(b), c2 = c.dot(c);
  centre->x = (a2 * (b.y - c.y) + b2 * (c.y - a.y) + c2 * (a.y - b.y)) / d;
  centre->y = (a2 * (c.x - b.x) + b2 * (a.x - c.x) + c2 * (b.x - a.x)) / d;
  *r = std::hypot(a.x - centre->x, a.y - centre->y);
  return true;
}

// RANSAC over 3-point circles near the prior (centre within max_shift, radius within
// 10 %), then a Huber-loss fit (Ceres) of the inliers. Deterministic (fixed seed).
struct CircleFit {
  cv::Point2d center;
  double radius = 0;
  double rms_px = 0;
  int inliers = 0;
};
CircleFit RansacCircle(const std::vector<cv::Point2d>& pts, cv::Point2d prior_c, double prior_r,
                       double max_shift, double tol) {
  CircleFit fit;
  if (pts.size() < 3) return fit;
  std::mt19937 rng(20240611u);
  std::uniform_int_distribution<std::size_t> pick(0, pts.size() - 1);
  std::vector<char> best_in;
  int best_count = -1;
  for (int it = 0; it < 400; ++it) {
    const std::size_t i = pick(rng), j = pick(rng), k = pick(rng);
    if (i == j || j == k || i == k) continue;
    cv::Point2d c;
    double r;
    if (!CircleThrough(pts[i], pts[j], pts[k], &c, &r)) continue;
    if (std::hypot(c.x - prior_c.x, c.y - prior_c.y) > max_shift ||
        std::abs(r - prior_r) > 0.1 * prior_r)
      continue;
    std::vector<char> in(pts.size(), 0);
    int count = 0;
    for (std::size_t p = 0; p < pts.size(); ++p) {
      if (std::abs(std::hypot(pts[p].x - c.x, pts[p].y - c.y) - r) <= tol) {
        in[p] = 1;
        ++count;
      }
    }
    if (count > best_count) {
      best_count = count;
      best_in = std::move(in);
    }
  }
  if (best_count < 3) return fit;
  std::vector<cv::Point2d> inliers;
  for (std::size_t p = 0; p < pts.size(); ++p) {
    if (best_in[p]) inliers.push_back(pts[p]);
  }
  const internal::CircleFitReport report = internal::FitConcentricCircles(
      {inliers}, {prior_c, {prior_r}}, internal::RobustLoss::kHuber, 1.0, tol);
  fit.center = report.circles.center_px;
  fit.radius = report.circles.radii_px[0];
  // Inliers of the final circle among all points.
  double sum2 = 0;
  for (const cv::Point2d& p : pts) {
    const double e = std::hypot(p.x - fit.center.x, p.y - fit.center.y) - fit.radius;
    if (std::abs(e) <= tol) {
      ++fit.inliers;
      sum2 += e * e;
    }
  }
  fit.rms_px = fit.inliers > 0 ? std::sqrt(sum2 / fit.inliers) : 0.0;
  return fit;
}

constexpr int kMinEdgePoints = 24;

void CheckFrames(const std::vector<cv::Mat>& frames) {
  if (frames.empty()) throw Error("AutoCalibrate: no image given");
  for (const cv::Mat& raw : frames) {
    if (raw.empty()) throw Error("AutoCalibrate: the image is empty");
    if (raw.cols < 16 || raw.rows < 16) {
      throw Error(StrCat("AutoCalibrate: image of ", raw.cols, "x", raw.rows,
                         " is too small to hold a ring"));
    }
    if (raw.depth() != CV_8U || (raw.channels() != 1 && raw.channels() != 3)) {
      throw Error(StrCat("AutoCalibrate: unsupported image (", raw.cols, "x", raw.rows, ", ",
                         raw.channels(), " channel(s), depth ", cv::depthToString(raw.depth()),
                         "); expected 8-bit grey or BGR"));
    }
    if (raw.size() != frames[0].size()) {
      throw Error(StrCat("AutoCalibrate: frames differ in size (", raw.cols, "x", raw.rows, " and ",
                         frames[0].cols, "x", frames[0].rows, ")"));
    }
  }
}

std::string Pct(double f) { return StrCat(static_cast<int>(std::lround(100.0 * f)), " %"); }

}  // namespace

void AutoCalibrationOptions::Validate() const {
  if (search_max_side_px < 64 || search_max_side_px > 2048) {
    throw Error(StrCat("AutoCalibrationOptions.search_max_side_px = ", search_max_side_px,
                       " must be in [64, 2048]"));
  }
  if (!(min_rim_confidence > 0 && min_rim_confidence <= 1)) {
    throw Error(StrCat("AutoCalibrationOptions.min_rim_confidence = ", min_rim_confidence,
                       " must be in (0, 1]"));
  }
  if (!(min_inner_confidence > 0 && min_inner_confidence <= 1)) {
    throw Error(StrCat("AutoCalibrationOptions.min_inner_confidence = ", min_inner_confidence,
                       " must be in (0, 1]"));
  }
}

AutoCalibrationResult AutoCalibrate(const cv::Mat& raw, const OmniCalibration& initial,
                                    const AutoCalibrationOptions& options) {
  return AutoCalibrate(std::vector<cv::Mat>{raw}, initial, options);
}

AutoCalibrationResult AutoCalibrate(const std::vector<cv::Mat>& frames,
                                    const OmniCalibration& initial,
                                    const AutoCalibrationOptions& options) {
  CheckFrames(frames);
  initial.Validate();
  options.Validate();
  const int width = frames[0].cols, height = frames[0].rows;
  const double max_side = std::max(width, height);
  const double fine_scale = std::min(1.0, options.search_max_side_px / max_side);
  const double coarse_scale = 0.5 * fine_scale;

  // Stage 1a: coarse grid over the middle of the image (centres in the central 60 %).
  std::vector<Gradients> coarse, fine, full;
  for (const cv::Mat& f : frames) {
    coarse.push_back(MakeGradients(f, coarse_scale));
    fine.push_back(MakeGradients(f, fine_scale));
  }
  const double cw = coarse[0].gx.cols, ch = coarse[0].gx.rows;
  const int r_lo = std::max(4, static_cast<int>(0.12 * std::min(cw, ch)));
  const int r_hi = static_cast<int>(0.6 * std::max(cw, ch));
  const double step = std::max(2.0, std::min(cw, ch) / 40.0);
  const Candidate coarse_best = SearchCircle(
      coarse, Grid({0.2 * cw, 0.2 * ch}, {0.8 * cw, 0.8 * ch}, step), 120, r_lo, r_hi, 2, 0.9);
  if (coarse_best.score <= 0) {
    throw Error(
        "no ring found (no circle with at least half of its length inside the image "
        "shows edges)");
  }
  // Stage 1b: refine on the finer image around the coarse circle.
  const double k = fine_scale / coarse_scale;
  const cv::Point2d c0 = coarse_best.center * k;
  const double r0 = coarse_best.radius * k;
  const double span = step * k;
  const Candidate fine_best =
      SearchCircle(fine, Grid(c0 - cv::Point2d(span, span), c0 + cv::Point2d(span, span), 1.0), 180,
                   static_cast<int>(0.93 * r0), static_cast<int>(std::ceil(1.07 * r0)), 1, 1.0);
  const cv::Point2d prior_c = fine_best.center / fine_scale;
  const double prior_r = fine_best.radius / fine_scale;

  // Stage 2: full-resolution edge points near the rim, RANSAC, robust fit.
  for (const cv::Mat& f : frames) full.push_back(MakeGradients(f, 1.0));
  constexpr int kRays = 720;
  const double w = 0.03 * prior_r + 3.0;
  std::vector<cv::Point2d> rim_points;
  int visible = 0;
  for (const Gradients& g : full) {
    const std::vector<cv::Point2d> p = EdgePoints(g, prior_c, prior_r, w, kRays, &visible);
    rim_points.insert(rim_points.end(), p.begin(), p.end());
  }
  const double tol = std::max(2.0, 0.01 * prior_r);
  const CircleFit rim = RansacCircle(rim_points, prior_c, prior_r, 0.05 * prior_r + 3.0, tol);
  AutoCalibrationResult result;
  result.frames_used = static_cast<int>(frames.size());
  result.visible_fraction = static_cast<double>(visible) / (kRays * frames.size());
  if (rim.inliers < kMinEdgePoints) {
    throw Error(StrCat("no ring found (only ", rim.inliers, " of ", rim_points.size(),
                       " rim edge points agree with one circle near radius ",
                       static_cast<int>(prior_r), " px around (", static_cast<int>(prior_c.x), ", ",
                       static_cast<int>(prior_c.y), "))"));
  }
  result.confidence = visible > 0 ? static_cast<double>(rim.inliers) / visible : 0.0;
  result.outer_inliers = rim.inliers;
  result.outer_residual_px = rim.rms_px;
  if (result.confidence < options.min_rim_confidence) {
    throw Error(StrCat("no ring found (the best rim, radius ", static_cast<int>(rim.radius),
                       " px around (", static_cast<int>(rim.center.x), ", ",
                       static_cast<int>(rim.center.y), "), has edges on ", Pct(result.confidence),
                       " of its visible rays; need ", Pct(options.min_rim_confidence), ")"));
  }
  if (!(rim.center.x >= 0 && rim.center.x <= width - 1 && rim.center.y >= 0 &&
        rim.center.y <= height - 1)) {
    throw Error(StrCat("no ring found (the fitted centre (", rim.center.x, ", ", rim.center.y,
                       ") lies outside the image)"));
  }
  result.calibration = initial;
  result.calibration.center_x_px = rim.center.x;
  result.calibration.center_y_px = rim.center.y;
  result.calibration.outer_radius_px = rim.radius;
  if (!options.find_inner) {
    result.calibration.inner_radius_px = 0.0;
    return result;
  }

  // Stage 3: the inner boundary, concentric with the rim.
  const cv::Point2d fc = rim.center * fine_scale;
  const double fr = rim.radius * fine_scale;
  const int in_lo = std::max(2, static_cast<int>(0.08 * fr));
  const int in_hi = static_cast<int>(0.75 * fr);
  const Candidate inner_best = SearchCircle(fine, {fc}, 180, in_lo, in_hi, 1, 0.9);
  result.inner_confidence = std::max(0.0, inner_best.score);
  if (result.inner_confidence < options.min_inner_confidence) {
    throw Error(
        StrCat("no ring found (no inner boundary: the best circle inside the rim has edges "
               "on ",
               Pct(result.inner_confidence), " of its rays; need ",
               Pct(options.min_inner_confidence), ")"));
  }
  // Refinement: edge points near the found radius; RANSAC keeps one circle's points (the
  // robot's body need not be concentric with the rim); the inner radius is their median
  // distance from the rim's centre. Without enough points the search's radius stays.
  const double ir = inner_best.radius / fine_scale;
  std::vector<cv::Point2d> inner_points;
  int inner_visible = 0;
  for (const Gradients& g : full) {
    const std::vector<cv::Point2d> p =
        EdgePoints(g, rim.center, ir, 0.03 * ir + 3.0, kRays, &inner_visible);
    inner_points.insert(inner_points.end(), p.begin(), p.end());
  }
  const double inner_tol = std::max(2.0, 0.01 * ir);
  const CircleFit inner = RansacCircle(inner_points, rim.center, ir, 0.1 * ir + 3.0, inner_tol);
  result.inner_inliers = inner.inliers;
  result.inner_residual_px = inner.rms_px;
  result.calibration.inner_radius_px = ir;
  if (inner.inliers >= kMinEdgePoints) {
    std::vector<double> d;
    for (const cv::Point2d& p : inner_points) {
      const double e = std::hypot(p.x - inner.center.x, p.y - inner.center.y) - inner.radius;
      if (std::abs(e) <= inner_tol) d.push_back(std::hypot(p.x - rim.center.x, p.y - rim.center.y));
    }
    std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
    result.calibration.inner_radius_px = d[d.size() / 2];
  }
  if (!(result.calibration.inner_radius_px < result.calibration.outer_radius_px)) {
    throw Error(StrCat("no ring found (fitted radii ", result.calibration.inner_radius_px, " and ",
                       result.calibration.outer_radius_px, " px are inconsistent)"));
  }
  return result;
}

FisheyeCalibration AutoCalibrateFisheye(const std::vector<cv::Mat>& frames,
                                        const FisheyeCalibration& initial,
                                        AutoCalibrationResult* result) {
  initial.Validate();
  AutoCalibrationOptions options;
  options.find_inner = false;
  OmniCalibration ring;
  ring.panorama_width = initial.panorama_width;
  ring.panorama_height = initial.panorama_height;
  const AutoCalibrationResult r = AutoCalibrate(frames, ring, options);
  FisheyeCalibration f = initial;
  f.center_x_px = r.calibration.center_x_px;
  f.center_y_px = r.calibration.center_y_px;
  f.circle_radius_px = r.calibration.outer_radius_px;
  if (result != nullptr) *result = r;
  return f;
}

cv::Mat DrawCalibrationOverlay(const cv::Mat& raw, const CameraCalibration& calibration) {
  cv::Mat out;
  if (raw.channels() == 1) {
    cv::cvtColor(raw, out, cv::COLOR_GRAY2BGR);
  } else {
    out = raw.clone();
  }
  const int thickness = std::max(2, std::max(out.cols, out.rows) / 400);
  constexpr int kShift = 4;  // sub-pixel drawing: coordinates in 1/16 px
  const auto fixed = [](cv::Point2d p) {
    return cv::Point(static_cast<int>(std::lround(p.x * 16)),
                     static_cast<int>(std::lround(p.y * 16)));
  };
  const auto circle = [&](cv::Point2d c, double r, cv::Scalar colour) {
    cv::circle(out, fixed(c), static_cast<int>(std::lround(r * 16)), colour, thickness, cv::LINE_AA,
               kShift);
  };
  // Ring or fisheye: circles of the panorama's first and last rows, the centre, column 0.
  const int w = calibration.panorama_width(), h = calibration.panorama_height();
  cv::Point2d centre;
  if (calibration.model == CameraModelType::kRing) {
    centre = {calibration.ring.center_x_px, calibration.ring.center_y_px};
    circle(centre, calibration.ring.outer_radius_px, cv::Scalar(0, 255, 0));
    circle(centre, calibration.ring.inner_radius_px, cv::Scalar(0, 255, 255));
  } else if (calibration.model == CameraModelType::kFisheye) {
    centre = {calibration.fisheye.center_x_px, calibration.fisheye.center_y_px};
    circle(centre, calibration.fisheye.circle_radius_px, cv::Scalar(0, 255, 0));
    for (const double row : {-0.5, h - 0.5}) {
      const cv::Point2d p = PanoramaToImage(calibration, 0, row, out.cols, out.rows);
      circle(centre, std::hypot(p.x - centre.x, p.y - centre.y), cv::Scalar(0, 255, 255));
    }
  } else {
    // Equirectangular: the band's top and bottom rows as horizontal lines.
    for (const double row : {-0.5, h - 0.5}) {
      const cv::Point2d p = PanoramaToImage(calibration, 0, row, out.cols, out.rows);
      cv::line(out, cv::Point(0, static_cast<int>(p.y)),
               cv::Point(out.cols - 1, static_cast<int>(p.y)), cv::Scalar(0, 255, 255), thickness,
               cv::LINE_AA);
    }
    const cv::Point2d p0 = PanoramaToImage(calibration, 0, 0, out.cols, out.rows);
    cv::line(out, cv::Point(static_cast<int>(p0.x), 0),
             cv::Point(static_cast<int>(p0.x), out.rows - 1), cv::Scalar(255, 0, 255), thickness,
             cv::LINE_AA);
    return out;
  }
  const double arm = std::max(6.0, 0.02 * std::max(out.cols, out.rows));
  cv::line(out, fixed(centre - cv::Point2d(arm, 0)), fixed(centre + cv::Point2d(arm, 0)),
           cv::Scalar(0, 0, 255), thickness, cv::LINE_AA, kShift);
  cv::line(out, fixed(centre - cv::Point2d(0, arm)), fixed(centre + cv::Point2d(0, arm)),
           cv::Scalar(0, 0, 255), thickness, cv::LINE_AA, kShift);
  // Direction of panorama column 0 (the robot's forward axis), from the first row.
  const cv::Point2d forward = PanoramaToImage(calibration, 0, 0, out.cols, out.rows);
  cv::line(out, fixed(centre), fixed(forward), cv::Scalar(255, 0, 255), thickness, cv::LINE_AA,
           kShift);
  (void)w;
  return out;
}

}  // namespace omnicml
