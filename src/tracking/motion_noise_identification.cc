#include "omnicml/tracking/motion_noise_identification.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/LU>

#include "omnicml/common/common.h"
#include "omnicml/geometry/chi_square.h"

namespace omnicml {
namespace {

// Prefix sums over steps i <= t of the terms of
//   B(s, t) = sum_{i in (s, t]} P_i + q_i h_i^T + h_i q_i^T + s_i h_i h_i^T,
//   h_i = R (p_t - p_i) = c - g_i,  c = R p_t,  g_i = R p_i,  R = rotation by +90 deg,
// where W_i = V_i M_i V_i^T = [[P_i, q_i], [q_i^T, s_i]] is the noise injected by step i
// (from pose i-1 to pose i) and [[I, h_i], [0, 1]] carries it from pose i to pose t
// (the product of the state Jacobians G of the steps after i).
struct Prefix {
  Eigen::Matrix2d p = Eigen::Matrix2d::Zero();
  Eigen::Vector2d q = Eigen::Vector2d::Zero();
  Eigen::Matrix2d qg = Eigen::Matrix2d::Zero();  // q g^T
  double s = 0.0;
  Eigen::Vector2d sg = Eigen::Vector2d::Zero();
  Eigen::Matrix2d sgg = Eigen::Matrix2d::Zero();  // s g g^T
};

// The median of the chi-square distribution with 2 degrees of freedom, 2 ln 2.
constexpr double kChiSquare2Median = 1.3862943611198906;

Eigen::Vector2d Rotate90(const Pose2& p) { return Eigen::Vector2d(-p.y(), p.x()); }

Prefix Minus(const Prefix& a, const Prefix& b) {
  Prefix d;
  d.p = a.p - b.p;
  d.q = a.q - b.q;
  d.qg = a.qg - b.qg;
  d.s = a.s - b.s;
  d.sg = a.sg - b.sg;
  d.sgg = a.sgg - b.sgg;
  return d;
}

Eigen::Matrix2d Evaluate(const Prefix& d, const Eigen::Vector2d& c) {
  Eigen::Matrix2d b = d.p + d.q * c.transpose() + c * d.q.transpose() - d.qg - d.qg.transpose() +
                      d.s * c * c.transpose() - c * d.sg.transpose() - d.sg * c.transpose() + d.sgg;
  return 0.5 * (b + b.transpose());
}

// One pair's innovation, its covariance bases and its fixed covariance (start poses).
struct Term {
  Eigen::Vector2d r;
  std::array<Eigen::Matrix2d, 4> b;
  Eigen::Matrix2d fixed = Eigen::Matrix2d::Zero();
};

// S = F + sum_j a_j B_j + rho I (theta = ln a_1..ln a_4, ln rho).
Eigen::Matrix2d Covariance(const Term& t, const std::array<double, 5>& value) {
  Eigen::Matrix2d s = t.fixed + value[4] * Eigen::Matrix2d::Identity();
  for (int j = 0; j < 4; ++j) s += value[j] * t.b[j];
  return s;
}

double Nis(const Term& t, const std::array<double, 5>& value) {
  const Eigen::Matrix2d s = Covariance(t, value);
  return t.r.dot(s.inverse() * t.r);
}

// Negative log-likelihood (up to constants) of the terms flagged in `use`.
double NegLogLikelihood(const std::vector<Term>& terms, const std::vector<char>& use,
                        const std::array<double, 5>& value) {
  double sum = 0.0;
  for (std::size_t k = 0; k < terms.size(); ++k) {
    if (!use[k]) continue;
    const Eigen::Matrix2d s = Covariance(terms[k], value);
    const double det = s.determinant();
    if (!(det > 0)) return std::numeric_limits<double>::infinity();
    sum += std::log(det) + terms[k].r.dot(s.inverse() * terms[k].r);
  }
  return sum;
}

// Cyclic coordinate search on ln(value), golden section within [lo, hi] per coordinate.
void Fit(const std::vector<Term>& terms, const std::vector<char>& use,
         const std::array<double, 5>& lo, const std::array<double, 5>& hi, int sweeps,
         std::array<double, 5>* value) {
  constexpr double kInvPhi = 0.6180339887498949;
  for (int sweep = 0; sweep < sweeps; ++sweep) {
    for (int j = 0; j < 5; ++j) {
      double a = std::log(lo[j]), b = std::log(hi[j]);
      auto f = [&](double x) {
        std::array<double, 5> v = *value;
        v[j] = std::exp(x);
        return NegLogLikelihood(terms, use, v);
      };
      double x1 = b - kInvPhi * (b - a), x2 = a + kInvPhi * (b - a);
      double f1 = f(x1), f2 = f(x2);
      for (int it = 0; it < 60 && b - a > 1e-4; ++it) {
        if (f1 <= f2) {
          b = x2;
          x2 = x1;
          f2 = f1;
          x1 = b - kInvPhi * (b - a);
          f1 = f(x1);
        } else {
          a = x1;
          x1 = x2;
          f1 = f2;
          x2 = a + kInvPhi * (b - a);
          f2 = f(x2);
        }
      }
      const double x = 0.5 * (a + b);
      // Keep the current value unless the search found a better one.
      if (f(x) <= f(std::log((*value)[j]))) (*value)[j] = std::exp(x);
    }
  }
}

}  // namespace

void MotionNoiseIdentificationOptions::Validate() const {
  auto fail = [](const char* field, const char* rule) {
    throw Error(StrCat("MotionNoiseIdentificationOptions.", field, " must be ", rule));
  };
  if (!(min_parameter > 0 && min_parameter < max_parameter && std::isfinite(max_parameter))) {
    fail("min_parameter/max_parameter", "0 < min < max");
  }
  if (!(min_appearance_variance_m2 > 0 && min_appearance_variance_m2 < max_appearance_variance_m2 &&
        std::isfinite(max_appearance_variance_m2))) {
    fail("min_appearance_variance_m2/max_appearance_variance_m2", "0 < min < max");
  }
  if (!(outlier_confidence > 0 && outlier_confidence < 1)) fail("outlier_confidence", "in (0, 1)");
  if (min_pairs < 1) fail("min_pairs", ">= 1");
  if (sweeps < 1) fail("sweeps", ">= 1");
  if (max_rounds < 1) fail("max_rounds", ">= 1");
}

namespace {

using Prefixes = std::array<std::vector<Prefix>, 4>;

// prefix[j][t]: the sums over steps 1..t of the poses for unit parameter j.
Prefixes BuildPrefixes(const std::vector<Pose2>& odometry) {
  const int n = static_cast<int>(odometry.size());
  Prefixes prefix;
  for (auto& v : prefix) v.assign(static_cast<std::size_t>(std::max(n, 1)), Prefix{});
  for (int i = 1; i < n; ++i) {
    const OdometryIncrement u = ComputeIncrement(odometry[i - 1], odometry[i]);
    const Eigen::Matrix3d v = MotionJacobianControl(odometry[i - 1], u);
    const Eigen::Vector2d g = Rotate90(odometry[i]);
    for (int j = 0; j < 4; ++j) {
      MotionNoise unit{0, 0, 0, 0};
      (j == 0 ? unit.a1 : j == 1 ? unit.a2 : j == 2 ? unit.a3 : unit.a4) = 1.0;
      const Eigen::Matrix3d w = v * MotionNoiseCovariance(u, unit) * v.transpose();
      const Eigen::Vector2d q = w.block<2, 1>(0, 2);
      const double s = w(2, 2);
      Prefix x = prefix[j][i - 1];
      x.p += w.block<2, 2>(0, 0);
      x.q += q;
      x.qg += q * g.transpose();
      x.s += s;
      x.sg += s * g;
      x.sgg += s * g * g.transpose();
      prefix[j][i] = x;
    }
  }
  return prefix;
}

// B_j(s, t) for a session's prefixes.
std::array<Eigen::Matrix2d, 4> Bases(const Prefixes& prefix, const std::vector<Pose2>& odometry,
                                     int s, int t) {
  std::array<Eigen::Matrix2d, 4> b;
  const Eigen::Vector2d c = Rotate90(odometry[t]);
  for (int j = 0; j < 4; ++j) b[j] = Evaluate(Minus(prefix[j][t], prefix[j][s]), c);
  return b;
}

// The xy covariance at pose t of a start error with covariance c0 at pose 0.
Eigen::Matrix2d StartCovarianceAt(const std::vector<Pose2>& poses, int t,
                                  const Eigen::Matrix3d& c0) {
  Eigen::Matrix<double, 2, 3> phi;
  const Eigen::Vector2d lever = Rotate90(poses[t]) - Rotate90(poses[0]);
  phi << 1.0, 0.0, lever.x(), 0.0, 1.0, lever.y();
  return phi * c0 * phi.transpose();
}

MotionNoiseIdentification Identify(const std::vector<Term>& terms,
                                   const MotionNoiseIdentificationOptions& options);

}  // namespace

std::vector<std::array<Eigen::Matrix2d, 4>> LoopDriftBases(const std::vector<Pose2>& odometry,
                                                           const std::vector<LoopPair>& pairs) {
  const int n = static_cast<int>(odometry.size());
  for (const LoopPair& p : pairs) {
    if (p.first < 0 || p.second >= n || p.first > p.second) {
      throw Error(StrCat("loop pair (", p.first, ", ", p.second, ") out of range or not ordered (",
                         n, " poses)"));
    }
  }
  const Prefixes prefix = BuildPrefixes(odometry);
  std::vector<std::array<Eigen::Matrix2d, 4>> out(pairs.size());
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    out[k] = Bases(prefix, odometry, pairs[k].first, pairs[k].second);
  }
  return out;
}

MotionNoiseIdentification IdentifyMotionNoise(const std::vector<OdometrySession>& sessions,
                                              const std::vector<SessionLoopPair>& pairs,
                                              const MotionNoiseIdentificationOptions& options) {
  options.Validate();
  const int ns = static_cast<int>(sessions.size());
  auto in_range = [&](int session, int index) {
    return session >= 0 && session < ns && index >= 0 &&
           index < static_cast<int>(sessions[static_cast<std::size_t>(session)].poses.size());
  };
  for (const SessionLoopPair& p : pairs) {
    const bool ordered = p.first_session < p.second_session ||
                         (p.first_session == p.second_session && p.first <= p.second);
    if (!in_range(p.first_session, p.first) || !in_range(p.second_session, p.second) || !ordered) {
      throw Error(StrCat("loop pair (", p.first_session, ":", p.first, ", ", p.second_session, ":",
                         p.second, ") out of range or not ordered"));
    }
    if (p.first_session != p.second_session &&
        !(sessions[p.first_session].known_start && sessions[p.second_session].known_start)) {
      throw Error(StrCat("loop pair (", p.first_session, ":", p.first, ", ", p.second_session, ":",
                         p.second, ") across sessions needs both starts known"));
    }
  }
  std::vector<Prefixes> prefixes;
  for (const OdometrySession& s : sessions) prefixes.push_back(BuildPrefixes(s.poses));
  std::vector<Term> terms(pairs.size());
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const SessionLoopPair& p = pairs[k];
    const OdometrySession& a = sessions[p.first_session];
    const OdometrySession& b = sessions[p.second_session];
    const Pose2& pa = a.poses[p.first];
    const Pose2& pb = b.poses[p.second];
    terms[k].r = Eigen::Vector2d(pb.x() - pa.x(), pb.y() - pa.y());
    if (p.first_session == p.second_session) {
      terms[k].b = Bases(prefixes[p.first_session], a.poses, p.first, p.second);
    } else {
      const auto ba = Bases(prefixes[p.first_session], a.poses, 0, p.first);
      const auto bb = Bases(prefixes[p.second_session], b.poses, 0, p.second);
      for (int j = 0; j < 4; ++j) terms[k].b[j] = ba[j] + bb[j];
      terms[k].fixed = StartCovarianceAt(a.poses, p.first, a.start_covariance) +
                       StartCovarianceAt(b.poses, p.second, b.start_covariance);
    }
  }
  return Identify(terms, options);
}

MotionNoiseIdentification IdentifyMotionNoise(const std::vector<Pose2>& odometry,
                                              const std::vector<LoopPair>& pairs,
                                              const MotionNoiseIdentificationOptions& options) {
  OdometrySession session;
  session.poses = odometry;
  std::vector<SessionLoopPair> session_pairs;
  for (const LoopPair& p : pairs) session_pairs.push_back(SessionLoopPair{0, p.first, 0, p.second});
  return IdentifyMotionNoise({session}, session_pairs, options);
}

namespace {

MotionNoiseIdentification Identify(const std::vector<Term>& terms,
                                   const MotionNoiseIdentificationOptions& options) {
  MotionNoiseIdentification result;
  result.pairs = static_cast<int>(terms.size());
  if (result.pairs < options.min_pairs) return result;

  const std::array<double, 5> lo{options.min_parameter, options.min_parameter,
                                 options.min_parameter, options.min_parameter,
                                 options.min_appearance_variance_m2};
  const std::array<double, 5> hi{options.max_parameter, options.max_parameter,
                                 options.max_parameter, options.max_parameter,
                                 options.max_appearance_variance_m2};
  // Start from the geometric middle of the bounds.
  std::array<double, 5> value;
  for (int j = 0; j < 5; ++j) value[j] = std::sqrt(lo[j] * hi[j]);
  const double gate = ChiSquareQuantile(options.outlier_confidence, 2);
  std::vector<char> use(terms.size(), 1);
  for (int round = 0; round < options.max_rounds; ++round) {
    Fit(terms, use, lo, hi, options.sweeps, &value);
    // The NIS scaled so that the median of the pairs in use is the chi-square median:
    // while aliases inflate the fit, the inliers' NIS are uniformly too small, and the
    // scaling (robust to a minority of aliases) restores the gate's meaning.
    std::vector<double> nis_used;
    for (std::size_t k = 0; k < terms.size(); ++k) {
      if (use[k]) nis_used.push_back(Nis(terms[k], value));
    }
    if (nis_used.empty()) break;
    std::nth_element(nis_used.begin(),
                     nis_used.begin() + static_cast<std::ptrdiff_t>(nis_used.size() / 2),
                     nis_used.end());
    const double median = nis_used[nis_used.size() / 2];
    const double scale = median > 0 ? kChiSquare2Median / median : 1.0;
    std::vector<char> next(terms.size(), 0);
    for (std::size_t k = 0; k < terms.size(); ++k) next[k] = scale * Nis(terms[k], value) <= gate;
    if (next == use) break;
    use = std::move(next);
  }
  // The final fit starts from the same point as the first, so the estimate depends on the
  // inlier set only, not on the path of the rejection rounds.
  for (int j = 0; j < 5; ++j) value[j] = std::sqrt(lo[j] * hi[j]);
  Fit(terms, use, lo, hi, options.sweeps, &value);
  std::vector<double> nis;
  for (std::size_t k = 0; k < terms.size(); ++k) {
    if (use[k]) nis.push_back(Nis(terms[k], value));
  }
  result.pairs_used = static_cast<int>(nis.size());
  if (result.pairs_used < options.min_pairs) return result;
  result.identified = true;
  result.noise = MotionNoise{value[0], value[1], value[2], value[3]};
  result.appearance_variance_m2 = value[4];
  double sum = 0.0;
  for (double x : nis) sum += x;
  result.mean_nis = sum / static_cast<double>(nis.size());
  std::nth_element(nis.begin(), nis.begin() + static_cast<std::ptrdiff_t>(nis.size() / 2),
                   nis.end());
  result.median_nis = nis[nis.size() / 2];
  return result;
}

}  // namespace

}  // namespace omnicml
