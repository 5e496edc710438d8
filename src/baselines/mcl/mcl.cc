#include "omnicml/baselines/mcl/mcl.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>

#include "omnicml/common/common.h"
#include "omnicml/common/options.h"
#include "omnicml/logs/antworld.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {

bool FiniteNonNeg(double v) { return std::isfinite(v) && v >= 0; }

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

}  // namespace

void MclOptions::Validate() const {
  auto fail = [](const std::string& field, const std::string& what) {
    throw Error(StrCat("mcl: ", field, ": ", what));
  };
  if (num_particles < 10) fail("num_particles", StrCat("must be >= 10, got ", num_particles));
  if (random_samples_per_step < 0 || random_samples_per_step > num_particles / 2) {
    fail("random_samples_per_step",
         StrCat("must be in [0, num_particles / 2], got ", random_samples_per_step));
  }
  if (!(alpha_fast > 0 && alpha_fast <= 1)) fail("alpha_fast", "must be in (0, 1]");
  if (!(alpha_slow > 0 && alpha_slow < alpha_fast)) {
    fail("alpha_slow", "must be in (0, alpha_fast)");
  }
  if (!(max_injection_fraction >= 0 && max_injection_fraction <= 0.5)) {
    fail("max_injection_fraction", "must be in [0, 0.5]");
  }
  if (!(lost_likelihood_ratio > 0 && lost_likelihood_ratio <= 1)) {
    fail("lost_likelihood_ratio", "must be in (0, 1]");
  }
  if (lost_after_steps < 1) {
    fail("lost_after_steps", StrCat("must be >= 1, got ", lost_after_steps));
  }
  if (!(lost_injection_fraction > 0 && lost_injection_fraction <= 0.5)) {
    fail("lost_injection_fraction", "must be in (0, 0.5]");
  }
  if (!(relative_heading_half_width_rad > 0 && relative_heading_half_width_rad <= kPi)) {
    fail("relative_heading_half_width_rad", "must be in (0, pi]");
  }
  if (!(injection_near_retrieved_fraction >= 0 && injection_near_retrieved_fraction <= 1)) {
    fail("injection_near_retrieved_fraction", "must be in [0, 1]");
  }
  try {
    motion.Validate();
  } catch (const Error& e) {
    fail("motion", e.what());
  }
  if (!(heading_gate_half_width_rad > 0) || !std::isfinite(heading_gate_half_width_rad)) {
    fail("heading_gate_half_width_rad", "must be > 0");
  }
  if (top_k < 0) fail("top_k", "must be >= 0");
  if (!(prior_fraction >= 0 && prior_fraction <= 1)) fail("prior_fraction", "must be in [0, 1]");
  if (!(min_likelihood > 0) || !std::isfinite(min_likelihood)) {
    fail("min_likelihood", "must be > 0");
  }
  if (!std::isfinite(axis_offset_rad)) fail("axis_offset_rad", "must be finite");
  try {
    visibility.Validate();
  } catch (const Error& e) {
    fail("visibility", e.what());
  }
  if (!FiniteNonNeg(visibility_radius_spacings)) {
    fail("visibility_radius_spacings", "must be >= 0");
  }
  if (!(cluster_cell_m > 0) || !std::isfinite(cluster_cell_m))
    fail("cluster_cell_m", "must be > 0");
  if (!(cluster_radius_m > 0) || !std::isfinite(cluster_radius_m)) {
    fail("cluster_radius_m", "must be > 0");
  }
  if (!FiniteNonNeg(init_sigma_xy_m)) fail("init_sigma_xy_m", "must be >= 0");
  if (!FiniteNonNeg(init_sigma_phi_rad)) fail("init_sigma_phi_rad", "must be >= 0");
}

std::shared_ptr<const DescriptorExtractor> MakeMclHeadingExtractor() {
  DescriptorOptions o;
  o.kind = DescriptorKind::kFourier;
  return MakeDescriptorExtractor(o);
}

double MedianReferenceSpacing(const std::vector<MclReference>& references) {
  constexpr double kCoincidentM = 1e-3;
  std::vector<double> steps;
  for (std::size_t i = 1; i < references.size(); ++i) {
    const double d =
        (references[i].map_T_robot.head<2>() - references[i - 1].map_T_robot.head<2>()).norm();
    if (d >= kCoincidentM) steps.push_back(d);
  }
  if (steps.empty()) return 0.0;
  const auto mid = steps.begin() + static_cast<std::ptrdiff_t>(steps.size() / 2);
  std::nth_element(steps.begin(), mid, steps.end());
  return *mid;
}

double VisibilityRadius(const OccupancyGrid& grid, const MclOptions& options,
                        const std::vector<MclReference>& references) {
  if (options.visibility.max_distance_from_reference_m > 0) {
    return options.visibility.max_distance_from_reference_m;
  }
  if (options.visibility_radius_spacings <= 0) return 0.0;
  const double spacing = MedianReferenceSpacing(references);
  if (spacing <= 0) return 0.0;  // one place only: nothing to scale by
  return std::max(options.visibility_radius_spacings * spacing, grid.resolution_m());
}

double ComputeVisibilityAreas(const OccupancyGrid& grid, const MclOptions& options,
                              std::vector<MclReference>* references) {
  VisibilityOptions visibility = options.visibility;
  visibility.max_distance_from_reference_m = VisibilityRadius(grid, options, *references);
  for (MclReference& r : *references) {
    r.axis_rad = WrapAngle(r.map_T_robot.z() + options.axis_offset_rad);
    CellIndex lambda;
    r.visibility = VisibilityArea(grid, r.map_T_robot.head<2>(), r.axis_rad, visibility, &lambda);
    r.lambda.reset();
    if (!r.visibility.empty()) r.lambda = lambda;
  }
  return visibility.max_distance_from_reference_m;
}

// ----------------------------------------------------------------------------- filter

MonteCarloLocalizer::MonteCarloLocalizer(const MclOptions& options, OccupancyGrid grid,
                                         std::vector<MclReference> references,
                                         std::shared_ptr<const DescriptorExtractor> extractor)
    : options_(options),
      grid_(std::move(grid)),
      references_(std::move(references)),
      extractor_(std::move(extractor)),
      rng_(options.seed) {
  options_.Validate();
  if (!extractor_) throw Error("mcl: no descriptor extractor");
  if (references_.empty()) throw Error("mcl: no reference views");
  if (options_.relative_heading) heading_extractor_ = MakeMclHeadingExtractor();
  for (const auto& r : references_) {
    if (r.descriptor.kind != extractor_->kind()) {
      throw Error(StrCat("mcl: reference descriptor of kind ", ToString(r.descriptor.kind),
                         " but extractor of kind ", ToString(extractor_->kind())));
    }
  }
  free_cells_ = grid_.FreeCells();
  if (free_cells_.empty()) throw Error("mcl: the occupancy grid has no free cell");
  const int n_cells = static_cast<int>(grid_.cells().size());
  std::vector<int> counts(n_cells + 1, 0);
  for (const auto& r : references_) {
    for (int c : r.visibility) {
      OMNICML_CHECK(c >= 0 && c < n_cells) << "visibility cell " << c;
      ++counts[c + 1];
    }
  }
  cell_start_.assign(n_cells + 1, 0);
  for (int i = 0; i < n_cells; ++i) cell_start_[i + 1] = cell_start_[i] + counts[i + 1];
  cell_refs_.assign(cell_start_.back(), 0);
  std::vector<int> fill(cell_start_.begin(), cell_start_.end() - 1);
  for (int j = 0; j < static_cast<int>(references_.size()); ++j) {
    for (int c : references_[j].visibility) cell_refs_[fill[c]++] = j;
  }
}

Pose2 MonteCarloLocalizer::RandomFreePose() {
  std::uniform_int_distribution<std::size_t> pick(0, free_cells_.size() - 1);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  const CellIndex c = grid_.FromLinear(free_cells_[pick(rng_)]);
  const double res = grid_.resolution_m();
  const Eigen::Vector2d p =
      grid_.origin_m() + Eigen::Vector2d((c.x + u01(rng_)) * res, (c.y + u01(rng_)) * res);
  return MakePose(p.x(), p.y(), (2.0 * u01(rng_) - 1.0) * kPi);
}

Pose2 MonteCarloLocalizer::RandomPoseNearRetrieved(const std::vector<double>& xi,
                                                   const std::vector<double>& implied) {
  double total = 0;
  for (std::size_t j = 0; j < xi.size(); ++j) {
    if (!references_[j].visibility.empty()) total += xi[j];
  }
  if (!(total > 0)) return RandomFreePose();
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  const double r = u01(rng_) * total;
  std::size_t j = xi.size();  // the reference where the cumulative sum passes r
  double cumulative = 0;
  for (std::size_t i = 0; i < xi.size(); ++i) {
    if (references_[i].visibility.empty() || !(xi[i] > 0)) continue;
    j = i;  // the last valid one when rounding leaves r beyond the sum
    cumulative += xi[i];
    if (r < cumulative) break;
  }
  const std::vector<int>& area = references_[j].visibility;
  std::uniform_int_distribution<std::size_t> pick(0, area.size() - 1);
  const CellIndex c = grid_.FromLinear(area[pick(rng_)]);
  const double res = grid_.resolution_m();
  const Eigen::Vector2d p =
      grid_.origin_m() + Eigen::Vector2d((c.x + u01(rng_)) * res, (c.y + u01(rng_)) * res);
  double phi = (2.0 * u01(rng_) - 1.0) * kPi;
  if (j < implied.size() && std::isfinite(implied[j])) {
    // Within the gate of the heading this reference implies.
    phi = WrapAngle(implied[j] + phi / kPi * options_.relative_heading_half_width_rad);
  }
  return MakePose(p.x(), p.y(), phi);
}

int MonteCarloLocalizer::InjectionCount(double mean_likelihood, double max_likelihood,
                                        double best_likelihood) {
  if (options_.injection == MclInjection::kEveryStep) return options_.random_samples_per_step;
  if (options_.injection == MclInjection::kWhenLost) {
    // Lost detection: inconsistent = even the cloud's best particle explains the query much
    // worse than a particle at the best retrieved reference would; lost after
    // lost_after_steps of those in a row. The best particle, not the mean: during an
    // aliasing episode the true place's references still rank within top_k, so some
    // particles keep eq. (7) support (mcl.h: ratio >= 0.26 on home_store seeds 1-5),
    // whereas a kidnapped cloud falls to the eq. (8) prior (ratio ~ prior_fraction).
    last_ratio_ = best_likelihood > 0 ? max_likelihood / best_likelihood : 1.0;
    inconsistent_steps_ =
        last_ratio_ < options_.lost_likelihood_ratio ? inconsistent_steps_ + 1 : 0;
    if (inconsistent_steps_ < options_.lost_after_steps) return 0;
    return static_cast<int>(std::lround(options_.lost_injection_fraction * options_.num_particles));
  }
  // Probabilistic Robotics, Table 8.3, lines 9-10 (averages start at the first value).
  if (!have_averages_) {
    w_slow_ = w_fast_ = mean_likelihood;
    have_averages_ = true;
  } else {
    w_slow_ += options_.alpha_slow * (mean_likelihood - w_slow_);
    w_fast_ += options_.alpha_fast * (mean_likelihood - w_fast_);
  }
  const double p = w_slow_ > 0 ? std::max(0.0, 1.0 - w_fast_ / w_slow_) : 0.0;
  const double n = std::min(p, options_.max_injection_fraction) * options_.num_particles;
  return static_cast<int>(std::lround(n));
}

void MonteCarloLocalizer::InitializeGlobal() {
  have_averages_ = false;
  inconsistent_steps_ = 0;
  particles_.assign(options_.num_particles, Particle{});
  const double w = 1.0 / options_.num_particles;
  for (Particle& p : particles_) {
    p.pose = RandomFreePose();
    p.weight = w;
  }
}

void MonteCarloLocalizer::InitializeAt(const Pose2& pose) {
  have_averages_ = false;
  inconsistent_steps_ = 0;
  particles_.assign(options_.num_particles, Particle{});
  std::normal_distribution<double> n01(0.0, 1.0);
  const double w = 1.0 / options_.num_particles;
  for (Particle& p : particles_) {
    p.pose = MakePose(pose.x() + options_.init_sigma_xy_m * n01(rng_),
                      pose.y() + options_.init_sigma_xy_m * n01(rng_),
                      pose.z() + options_.init_sigma_phi_rad * n01(rng_));
    p.weight = w;
  }
}

void MonteCarloLocalizer::Predict(const OdometryIncrement& u) {
  // [W] / Thrun et al.: sample_motion_model_odometry per particle.
  for (Particle& p : particles_) {
    p.pose = ApplyIncrement(p.pose, SampleOdometryIncrement(u, options_.motion, rng_));
  }
}

std::vector<double> MonteCarloLocalizer::Similarities(const Descriptor& query) const {
  if (query.kind != extractor_->kind()) {
    throw Error(StrCat("mcl: query descriptor of kind ", ToString(query.kind),
                       " but the map holds kind ", ToString(extractor_->kind())));
  }
  const std::size_t m = references_.size();
  std::vector<double> e(m);
  double e_max = 0;
  for (std::size_t j = 0; j < m; ++j) {
    e[j] = extractor_->Distance(query, references_[j].descriptor);
    e_max = std::max(e_max, e[j]);
  }
  std::vector<double> xi(m, 0.0);
  if (!(e_max > 0)) {  // every reference equals the query
    std::fill(xi.begin(), xi.end(), 1.0);
    return xi;
  }
  std::vector<std::size_t> order(m);
  std::iota(order.begin(), order.end(), 0);
  const std::size_t k =
      options_.top_k == 0 ? m : std::min<std::size_t>(m, static_cast<std::size_t>(options_.top_k));
  std::partial_sort(
      order.begin(), order.begin() + k, order.end(),
      [&](std::size_t a, std::size_t b) { return e[a] < e[b] || (e[a] == e[b] && a < b); });
  for (std::size_t i = 0; i < k; ++i) xi[order[i]] = 1.0 - e[order[i]] / e_max;
  return xi;
}

double MonteCarloLocalizer::Likelihood(const Pose2& pose, const std::vector<double>& xi) const {
  return Likelihood(pose, xi, {});
}

std::vector<double> MonteCarloLocalizer::ImpliedHeadings(const std::vector<double>& xi,
                                                         const Descriptor* heading_query) const {
  std::vector<double> out(references_.size(), kNaN);
  if (!heading_extractor_ || heading_query == nullptr || heading_query->features.empty()) {
    return out;
  }
  if (heading_query->kind != heading_extractor_->kind()) {
    throw Error(StrCat("mcl: heading descriptor of kind ", ToString(heading_query->kind),
                       ", expected ", ToString(heading_extractor_->kind())));
  }
  for (std::size_t j = 0; j < references_.size(); ++j) {
    const Descriptor& h = references_[j].heading_descriptor;
    if (!(xi[j] > 0) || h.features.empty()) continue;
    const std::optional<double> rel = heading_extractor_->RelativeHeading(*heading_query, h);
    if (rel) out[j] = WrapAngle(references_[j].map_T_robot.z() + *rel);
  }
  return out;
}

double MonteCarloLocalizer::Likelihood(const Pose2& pose, const std::vector<double>& xi,
                                       const std::vector<double>& implied) const {
  OMNICML_CHECK(xi.size() == references_.size());
  OMNICML_CHECK(implied.empty() || implied.size() == references_.size());
  const CellIndex c = grid_.CellOf(pose.head<2>());
  if (!grid_.IsFree(c)) return 0.0;
  const int cell = grid_.Linear(c);
  double k = 0, sum = 0;
  for (int a = cell_start_[cell]; a < cell_start_[cell + 1]; ++a) {
    const int j = cell_refs_[a];
    double d = 1.0;  // angular step function d(psi)
    if (!options_.heading_independent) {
      const double psi = WrapAngle(pose.z() - references_[j].map_T_robot.z());
      d = std::abs(psi) <= options_.heading_gate_half_width_rad ? 1.0 : 0.0;
    }
    k += d;
    double gate = 1.0;  // the heading the panoramas imply for reference j
    if (!implied.empty() && std::isfinite(implied[j]) &&
        std::abs(WrapAngle(pose.z() - implied[j])) > options_.relative_heading_half_width_rad) {
      gate = 0.0;
    }
    sum += xi[j] * d * gate;
  }
  if (k > 0) return sum / k;  // [W] eq. (7)
  // [W] eq. (8): outside every visibility area the prior applies.
  double s = 0;
  int n = 0;
  for (double x : xi) {
    if (x > 0) {
      s += x;
      ++n;
    }
  }
  return n > 0 ? options_.prior_fraction * s / n : options_.prior_fraction;
}

MclEstimate MonteCarloLocalizer::Estimate(const std::vector<Particle>& particles) const {
  MclEstimate est;
  double w_sum = 0, sx = 0, sy = 0, sc = 0, ss = 0, sxx = 0, syy = 0;
  for (const Particle& p : particles) {
    w_sum += p.weight;
    sx += p.weight * p.pose.x();
    sy += p.weight * p.pose.y();
    sc += p.weight * std::cos(p.pose.z());
    ss += p.weight * std::sin(p.pose.z());
  }
  if (!(w_sum > 0)) return est;
  const double mx = sx / w_sum, my = sy / w_sum;
  for (const Particle& p : particles) {
    sxx += p.weight * (p.pose.x() - mx) * (p.pose.x() - mx);
    syy += p.weight * (p.pose.y() - my) * (p.pose.y() - my);
  }
  est.mean = MakePose(mx, my, std::atan2(ss, sc));
  est.spread_m = Eigen::Vector2d(std::sqrt(sxx / w_sum), std::sqrt(syy / w_sum));

  // Best cluster: weight histogram on cluster_cell_m bins, the 3 x 3 window of largest
  // weight, then every particle within cluster_radius_m of that window's weighted mean.
  const double cell = options_.cluster_cell_m;
  const Eigen::Vector2d lo = grid_.origin_m();
  const int bw = static_cast<int>(std::ceil(grid_.width() * grid_.resolution_m() / cell)) + 1;
  const int bh = static_cast<int>(std::ceil(grid_.height() * grid_.resolution_m() / cell)) + 1;
  std::vector<double> hist(static_cast<std::size_t>(bw) * bh, 0.0);
  auto bin_of = [&](const Pose2& p, int* bx, int* by) {
    *bx = std::clamp(static_cast<int>(std::floor((p.x() - lo.x()) / cell)), 0, bw - 1);
    *by = std::clamp(static_cast<int>(std::floor((p.y() - lo.y()) / cell)), 0, bh - 1);
  };
  for (const Particle& p : particles) {
    int bx, by;
    bin_of(p.pose, &bx, &by);
    hist[static_cast<std::size_t>(by) * bw + bx] += p.weight;
  }
  double best = -1;
  int best_x = 0, best_y = 0;
  for (int y = 0; y < bh; ++y) {
    for (int x = 0; x < bw; ++x) {
      double s = 0;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const int xx = x + dx, yy = y + dy;
          if (xx >= 0 && yy >= 0 && xx < bw && yy < bh)
            s += hist[static_cast<std::size_t>(yy) * bw + xx];
        }
      }
      if (s > best) {
        best = s;
        best_x = x;
        best_y = y;
      }
    }
  }
  double wx = 0, wy = 0, ww = 0;
  for (const Particle& p : particles) {
    int bx, by;
    bin_of(p.pose, &bx, &by);
    if (std::abs(bx - best_x) <= 1 && std::abs(by - best_y) <= 1) {
      wx += p.weight * p.pose.x();
      wy += p.weight * p.pose.y();
      ww += p.weight;
    }
  }
  const Eigen::Vector2d seed(wx / ww, wy / ww);
  const double r2 = options_.cluster_radius_m * options_.cluster_radius_m;
  double cx = 0, cy = 0, cc = 0, cs = 0, cw = 0;
  for (const Particle& p : particles) {
    if ((p.pose.head<2>() - seed).squaredNorm() > r2) continue;
    cx += p.weight * p.pose.x();
    cy += p.weight * p.pose.y();
    cc += p.weight * std::cos(p.pose.z());
    cs += p.weight * std::sin(p.pose.z());
    cw += p.weight;
  }
  if (cw > 0) {
    est.cluster = MakePose(cx / cw, cy / cw, std::atan2(cs, cc));
    est.cluster_weight = cw / w_sum;
  } else {
    est.cluster = est.mean;
    est.cluster_weight = 0;
  }
  return est;
}

MclEstimate MonteCarloLocalizer::Correct(const Descriptor& query, const Descriptor* heading_query) {
  OMNICML_CHECK(!particles_.empty()) << "Correct before Initialize";
  const std::vector<double> xi = Similarities(query);
  const std::vector<double> implied = ImpliedHeadings(xi, heading_query);
  double sum = 0, max_likelihood = 0;
  for (Particle& p : particles_) {
    p.weight = std::max(Likelihood(p.pose, xi, implied), options_.min_likelihood);
    sum += p.weight;
    max_likelihood = std::max(max_likelihood, p.weight);
  }
  // The likelihood of a particle at the best retrieved reference (its position, the
  // heading the panoramas imply or its own): what a consistent cloud would explain.
  double best_likelihood = 0;
  if (options_.injection == MclInjection::kWhenLost) {
    for (std::size_t j = 0; j < xi.size(); ++j) {
      if (!(xi[j] > 0)) continue;
      Pose2 at = references_[j].map_T_robot;
      if (std::isfinite(implied[j])) at.z() = implied[j];
      best_likelihood = std::max(best_likelihood, Likelihood(at, xi, implied));
    }
  }
  const double mean_likelihood = sum / static_cast<double>(particles_.size());
  double sum_sq = 0;
  for (Particle& p : particles_) {
    p.weight /= sum;
    sum_sq += p.weight * p.weight;
  }
  const MclEstimate est = Estimate(particles_);
  const int inject = InjectionCount(mean_likelihood, max_likelihood, best_likelihood);
  std::vector<Particle> next =
      LowVarianceResample(particles_, options_.num_particles - inject, rng_);
  // [W]'s random sample injection, a share of it near the retrieved references.
  next.reserve(options_.num_particles);
  const int near = static_cast<int>(
      std::lround(options_.injection_near_retrieved_fraction * static_cast<double>(inject)));
  for (int i = 0; i < inject; ++i) {
    next.push_back({i < near ? RandomPoseNearRetrieved(xi, implied) : RandomFreePose(), 0.0});
  }
  last_step_ = MclStepStats{.mean_likelihood = mean_likelihood,
                            .w_slow = w_slow_,
                            .w_fast = w_fast_,
                            .effective_sample_size = 1.0 / sum_sq,
                            .injected = inject,
                            .injected_near_retrieved = near,
                            .consistency_ratio = last_ratio_,
                            .inconsistent_steps = inconsistent_steps_,
                            .max_likelihood = max_likelihood,
                            .best_likelihood = best_likelihood,
                            .lost = options_.injection == MclInjection::kWhenLost &&
                                    inconsistent_steps_ >= options_.lost_after_steps};
  const double w = 1.0 / options_.num_particles;
  for (Particle& p : next) p.weight = w;
  particles_ = std::move(next);
  return est;
}

std::vector<Particle> LowVarianceResample(const std::vector<Particle>& particles, int n,
                                          std::mt19937_64& rng) {
  if (n < 1 || particles.empty()) throw Error("resample: need n >= 1 and a non-empty set");
  double total = 0;
  for (const Particle& p : particles) {
    if (!(p.weight >= 0) || !std::isfinite(p.weight)) throw Error("resample: bad weight");
    total += p.weight;
  }
  if (!(total > 0)) throw Error("resample: weights sum to zero");
  // Probabilistic Robotics, Table 4.4.
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  const double step = total / n;
  const double r = u01(rng) * step;
  std::vector<Particle> out;
  out.reserve(n);
  double c = particles[0].weight;
  std::size_t i = 0;
  for (int m = 0; m < n; ++m) {
    const double u = r + m * step;
    while (u > c && i + 1 < particles.size()) {
      ++i;
      c += particles[i].weight;
    }
    out.push_back({particles[i].pose, 1.0 / n});
  }
  return out;
}

// ----------------------------------------------------------------------------- sequences

std::vector<MclFrame> ReadMclFrames(FrameSource& source, const DescriptorExtractor& extractor,
                                    const std::vector<int>& sessions, int stride,
                                    const DescriptorExtractor* heading_extractor) {
  if (stride < 1) throw Error("mcl: stride must be >= 1");
  std::vector<MclFrame> out;
  Frame frame;
  auto wanted = [&](int s) {
    return sessions.empty() || std::find(sessions.begin(), sessions.end(), s) != sessions.end();
  };
  std::unique_ptr<OmniUnwrapper> unwrapper;
  int unwrapper_session = -1;
  int last = sessions.empty() ? source.NumSessions() - 1
                              : *std::max_element(sessions.begin(), sessions.end());
  while (source.Next(&frame)) {
    if (frame.session_index > last) break;
    if (!wanted(frame.session_index) || frame.index_in_session % stride != 0) continue;
    const SessionInfo& info = source.Session(frame.session_index);
    cv::Mat panorama = frame.image;
    cv::Mat valid_mask;  // empty: every pixel shows the scene
    if (info.camera.kind == ImageKind::kRawRing) {
      // One unwrapper per session (its calibration and ring size).
      if (unwrapper_session != frame.session_index) {
        try {
          unwrapper =
              std::make_unique<OmniUnwrapper>(info.camera.calibration, info.camera.image_width,
                                              info.camera.image_height, info.camera.mask);
        } catch (const Error& e) {
          throw Error(
              StrCat("mcl: session ", info.name, ": cannot unwrap its ring images: ", e.what()));
        }
        unwrapper_session = frame.session_index;
      }
      panorama = unwrapper->Unwrap(frame.image);
      // Pixels outside a clipped ring or under the user mask do not count (descriptor.h).
      valid_mask = unwrapper->MaskFor(panorama.cols, panorama.rows);
    }
    MclFrame f;
    f.index = frame.global_index;
    f.session = frame.session_index;
    f.stamp_s = frame.stamp_s;
    f.odom_T_robot = frame.odom_T_robot;
    f.truth = frame.map_T_robot_truth;
    f.descriptor = extractor.ComputeMasked(panorama, valid_mask);
    if (heading_extractor != nullptr)
      f.heading_descriptor = heading_extractor->ComputeMasked(panorama, valid_mask);
    out.push_back(std::move(f));
  }
  return out;
}

std::vector<MclReference> MakeReferences(const std::vector<MclFrame>& frames) {
  std::vector<MclReference> refs;
  for (const MclFrame& f : frames) {
    if (!f.truth) continue;
    MclReference r;
    r.map_T_robot = *f.truth;
    r.descriptor = f.descriptor;
    r.heading_descriptor = f.heading_descriptor;
    refs.push_back(std::move(r));
  }
  return refs;
}

std::vector<MclStepRecord> RunMcl(MonteCarloLocalizer& mcl, const std::vector<MclFrame>& frames,
                                  const MclRunSpec& spec) {
  std::vector<MclStepRecord> records;
  if (frames.empty()) return records;
  if (spec.known_start) {
    if (!frames[0].truth) throw Error("mcl: known start needs ground truth on the first frame");
    mcl.InitializeAt(*frames[0].truth);
  } else {
    mcl.InitializeGlobal();
  }
  const bool extra_noise = spec.extra_odometry_noise.a1 > 0 || spec.extra_odometry_noise.a2 > 0 ||
                           spec.extra_odometry_noise.a3 > 0 || spec.extra_odometry_noise.a4 > 0;
  std::mt19937_64 noise_rng(spec.noise_seed);
  std::size_t i = 0;
  std::size_t prev = 0;
  bool kidnapped = false;
  for (int step = 0; i < frames.size(); ++step) {
    if (spec.max_steps > 0 && step >= spec.max_steps) break;
    const MclFrame& f = frames[i];
    const auto t0 = std::chrono::steady_clock::now();
    if (step > 0) {
      OdometryIncrement u;  // zero after a kidnapping
      if (!kidnapped && frames[prev].session == f.session) {
        u = ComputeIncrement(frames[prev].odom_T_robot, f.odom_T_robot);
        if (extra_noise) u = SampleOdometryIncrement(u, spec.extra_odometry_noise, noise_rng);
      }
      mcl.Predict(u);
    }
    const MclEstimate est = mcl.Correct(f.descriptor, &f.heading_descriptor);
    const auto t1 = std::chrono::steady_clock::now();
    MclStepRecord r;
    r.step = step;
    r.frame = f.index;
    r.stamp_s = f.stamp_s;
    r.estimate = est;
    r.truth = f.truth;
    r.kidnapped = kidnapped;
    r.stats = mcl.last_step();
    r.time_us = std::chrono::duration<double, std::micro>(t1 - t0).count();
    if (f.truth) {
      r.position_error_m = (est.cluster.head<2>() - f.truth->head<2>()).norm();
      r.heading_error_rad = std::abs(WrapAngle(est.cluster.z() - f.truth->z()));
    }
    records.push_back(r);
    kidnapped = false;
    prev = i;
    if (step == spec.kidnap_step) {
      if (spec.kidnap_to_frame < 0 || spec.kidnap_to_frame >= static_cast<int>(frames.size())) {
        throw Error(StrCat("mcl: kidnap_to_frame ", spec.kidnap_to_frame, " out of range"));
      }
      i = static_cast<std::size_t>(spec.kidnap_to_frame);
      kidnapped = true;
    } else {
      ++i;
    }
  }
  return records;
}

int StepsToConverge(const std::vector<MclStepRecord>& records, int from, double error_m,
                    double heading_rad, int hold) {
  int run = 0;
  for (int s = std::max(from, 0); s < static_cast<int>(records.size()); ++s) {
    const auto& r = records[s];
    const bool ok = r.position_error_m >= 0 && r.position_error_m < error_m &&
                    r.heading_error_rad < heading_rad;
    run = ok ? run + 1 : 0;
    if (run >= hold) return s - hold + 1 - from;
  }
  return -1;
}

// ---- options (the schema of the header's VisitFields, common/options.h)

MclOptions ParseMclOptionsYaml(const std::string& yaml_text, const std::string& source) {
  return ParseOptionsYaml<MclOptions>(yaml_text, source, MclOptions{}, kMclRunKeys);
}
MclOptions LoadMclOptions(const std::string& path) {
  return ParseMclOptionsYaml(ReadOptionFile(path), path);
}
std::string MclOptionsToYaml(const MclOptions& options) { return OptionsToYaml(options); }

}  // namespace omnicml
