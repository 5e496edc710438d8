#include "omnicml/tracking/motion_noise_identification.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/QR>

#include "omnicml/common/common.h"
#include "omnicml/geometry/chi_square.h"

namespace omnicml {
namespace {

constexpr int kP = kIdentifiedParameters;
using Vector6 = Eigen::Matrix<double, kP, 1>;
using Matrix6 = Eigen::Matrix<double, kP, kP>;

// Prefix sums over steps i <= t of the terms of the drift covariance from s to t
// (docs/design.md "Motion noise identified from loop innovations"):
//   B(s, t) = sum_{i in (s, t]} Phi_i W_i Phi_i^T,  Phi_i = [[I, h_i], [0, 1]],
//   xy block    sum P_i + q_i h_i^T + h_i q_i^T + s_i h_i h_i^T,
//   xy-phi      sum q_i + s_i h_i,
//   phi-phi     sum s_i,
//   h_i = R (p_t - p_i) = c - g_i,  c = R p_t,  g_i = R p_i,  R = rotation by +90 deg,
// where W_i = V_i M_i V_i^T = [[P_i, q_i], [q_i^T, s_i]] is the noise injected by step i
// (from pose i-1 to pose i) and Phi_i (the product of the state Jacobians G of the steps
// after i) carries it from pose i to pose t.
struct Prefix {
  Eigen::Matrix2d p = Eigen::Matrix2d::Zero();
  Eigen::Vector2d q = Eigen::Vector2d::Zero();
  Eigen::Matrix2d qg = Eigen::Matrix2d::Zero();  // q g^T
  double s = 0.0;
  Eigen::Vector2d sg = Eigen::Vector2d::Zero();
  Eigen::Matrix2d sgg = Eigen::Matrix2d::Zero();  // s g g^T
};

// Chi-square medians with 2 and 3 degrees of freedom.
constexpr double kChiSquareMedian[4] = {0.0, 0.45493642311957, 1.3862943611198906,
                                        2.3659738843753377};

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

// The drift covariance of the prefix difference d at the pose whose R p_t is c.
Eigen::Matrix3d Evaluate(const Prefix& d, const Eigen::Vector2d& c) {
  Eigen::Matrix3d b;
  const Eigen::Matrix2d xy = d.p + d.q * c.transpose() + c * d.q.transpose() - d.qg -
                             d.qg.transpose() + d.s * c * c.transpose() - c * d.sg.transpose() -
                             d.sg * c.transpose() + d.sgg;
  b.block<2, 2>(0, 0) = 0.5 * (xy + xy.transpose());
  const Eigen::Vector2d cross = d.q + d.s * c - d.sg;
  b.block<2, 1>(0, 2) = cross;
  b.block<1, 2>(2, 0) = cross.transpose();
  b(2, 2) = d.s;
  return b;
}

// A stretch of one session's dead reckoning whose heading drift a pair's heading
// innovation contains: the steps in (from, to], with `sign`; from = -1 also holds the
// session's start error (pose 0).
struct Segment {
  int session = 0;
  int from = 0;
  int to = 0;
  double sign = 1.0;
};

// One pair's innovation (x, y, phi; phi unused when dim is 2), its drift bases and its
// fixed covariance (start poses), and the stretches of dead reckoning it contains (the
// joint likelihood's covariances between pairs).
struct Term {
  Eigen::Vector3d r = Eigen::Vector3d::Zero();
  int dim = 2;
  std::array<Eigen::Matrix3d, 4> b;
  Eigen::Matrix3d fixed = Eigen::Matrix3d::Zero();
  std::array<Segment, 2> segments;
  int segment_count = 1;
};

// S = F + sum_j a_j B_j + diag(rho, rho, rho_phi) for parameter values v.
Eigen::Matrix3d Covariance(const Term& t, const Vector6& v) {
  Eigen::Matrix3d s = t.fixed;
  for (int j = 0; j < 4; ++j) s += v[j] * t.b[j];
  s(0, 0) += v[4];
  s(1, 1) += v[4];
  s(2, 2) += v[5];
  return s;
}

// Basis of parameter j in S (the offsets' are constant).
Eigen::Matrix3d Basis(const Term& t, int j) {
  if (j < 4) return t.b[j];
  Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
  if (j == 4) {
    a(0, 0) = a(1, 1) = 1.0;
  } else {
    a(2, 2) = 1.0;
  }
  return a;
}

template <int D>
double NisOf(const Term& t, const Vector6& v) {
  const Eigen::Matrix<double, D, D> s = Covariance(t, v).topLeftCorner<D, D>();
  const Eigen::Matrix<double, D, 1> r = t.r.head<D>();
  return r.dot(s.inverse() * r);
}

double Nis(const Term& t, const Vector6& v) { return t.dim == 3 ? NisOf<3>(t, v) : NisOf<2>(t, v); }

// -2 ln L of one pair and, when wanted, its gradient and Fisher information in the log
// parameters theta = ln v, with q = r^T S^-1 r.
// Gaussian (nu = 0): -2 ln L = ln det S + q, g_j = v_j (tr(S^-1 A_j) - r^T S^-1 A_j S^-1 r),
// F_jl = v_j v_l tr(S^-1 A_j S^-1 A_l).
// Student t (nu > 0; Lange, Little & Taylor, "Robust statistical modeling using the t
// distribution", JASA 1989): -2 ln L = ln det S + (nu + D) ln(1 + q / nu) (+ const), the
// gradient as above with the quadratic term weighted by w = (nu + D) / (nu + q), and the
// expected information F_jl = v_j v_l ((nu + D) tr(S^-1 A_j S^-1 A_l) - tr(S^-1 A_j)
// tr(S^-1 A_l)) / (nu + D + 2).
template <int D>
double AddTerm(const Term& t, const Vector6& v, double nu, Vector6* g, Matrix6* f) {
  const Eigen::Matrix<double, D, D> s = Covariance(t, v).topLeftCorner<D, D>();
  const double det = s.determinant();
  if (!(det > 0)) return std::numeric_limits<double>::infinity();
  const Eigen::Matrix<double, D, D> si = s.inverse();
  const Eigen::Matrix<double, D, 1> r = t.r.head<D>();
  const Eigen::Matrix<double, D, 1> alpha = si * r;
  const double q = r.dot(alpha);
  const double w = nu > 0 ? (nu + D) / (nu + q) : 1.0;
  if (g != nullptr) {
    std::array<Eigen::Matrix<double, D, D>, kP> m;
    for (int j = 0; j < kP; ++j) {
      const Eigen::Matrix<double, D, D> a = Basis(t, j).topLeftCorner<D, D>();
      m[j] = si * a;
      (*g)[j] += v[j] * (m[j].trace() - w * alpha.dot(a * alpha));
    }
    for (int j = 0; j < kP; ++j) {
      for (int l = j; l < kP; ++l) {
        double x = (m[j] * m[l]).trace();
        if (nu > 0) x = ((nu + D) * x - m[j].trace() * m[l].trace()) / (nu + D + 2);
        x *= v[j] * v[l];
        (*f)(j, l) += x;
        if (l != j) (*f)(l, j) += x;
      }
    }
  }
  return std::log(det) + (nu > 0 ? (nu + D) * std::log1p(q / nu) : q);
}

// The prior's -2 ln p(theta) (I5), and, when g is given, its gradient added to g and its
// Hessian added to prior.
double AddPrior(const Vector6& theta, const MotionNoiseIdentificationOptions& options, Vector6* g,
                Matrix6* prior) {
  double sum = 0.0;
  // Shape prior: d_j = ln(a_j / c_j), sum_j (d_j - mean d)^2 / sd^2.
  const MotionNoise& c = options.shape_prior;
  const std::array<double, 4> shape{c.a1, c.a2, c.a3, c.a4};
  std::array<double, 4> d;
  double mean = 0.0;
  for (int j = 0; j < 4; ++j) {
    d[j] = theta[j] - std::log(shape[j]);
    mean += 0.25 * d[j];
  }
  const double w = 1.0 / (options.shape_prior_log_sd * options.shape_prior_log_sd);
  for (int j = 0; j < 4; ++j) {
    sum += w * (d[j] - mean) * (d[j] - mean);
    if (g != nullptr) {
      (*g)[j] += 2.0 * w * (d[j] - mean);
      for (int l = 0; l < 4; ++l) (*prior)(j, l) += 2.0 * w * ((j == l ? 1.0 : 0.0) - 0.25);
    }
  }
  // Offset priors: ln(rho / rho_0) ~ N(0, sd^2), and the same for rho_phi.
  const double wo = 1.0 / (options.offset_prior_log_sd * options.offset_prior_log_sd);
  const double centre[2] = {std::log(options.appearance_variance_prior_m2),
                            std::log(options.heading_variance_prior_rad2)};
  for (int j = 4; j < kP; ++j) {
    const double e = theta[j] - centre[j - 4];
    sum += wo * e * e;
    if (g != nullptr) {
      (*g)[j] += 2.0 * wo * e;
      (*prior)(j, j) += 2.0 * wo;
    }
  }
  return sum;
}

// The objective: -2 ln posterior (up to constants) of the pairs flagged in `use`, its
// gradient in theta, and the Fisher information of the pairs (`data`) and the prior's
// Hessian (`prior`), both in -2 ln units.
struct Objective {
  const std::vector<Term>& terms;
  const std::vector<char>& use;
  const MotionNoiseIdentificationOptions& options;
  // Degrees of freedom of the pairs' likelihood: 0 Gaussian, > 0 Student t.
  double nu = 0.0;

  double operator()(const Vector6& theta, Vector6* g = nullptr, Matrix6* data = nullptr,
                    Matrix6* prior = nullptr) const {
    const Vector6 v = theta.array().exp();
    if (g != nullptr) {
      g->setZero();
      data->setZero();
      prior->setZero();
    }
    double sum = 0.0;
    for (std::size_t k = 0; k < terms.size(); ++k) {
      if (!use[k]) continue;
      sum += terms[k].dim == 3 ? AddTerm<3>(terms[k], v, nu, g, data)
                               : AddTerm<2>(terms[k], v, nu, g, data);
      if (!std::isfinite(sum)) return sum;
    }
    return sum + AddPrior(theta, options, g, prior);
  }
};

// Bounds of theta.
struct Box {
  Vector6 lo, hi;
};

Box Bounds(const MotionNoiseIdentificationOptions& o) {
  Box b;
  for (int j = 0; j < 4; ++j) {
    b.lo[j] = std::log(o.min_parameter);
    b.hi[j] = std::log(o.max_parameter);
  }
  b.lo[4] = std::log(o.min_appearance_variance_m2);
  b.hi[4] = std::log(o.max_appearance_variance_m2);
  b.lo[5] = std::log(o.min_heading_variance_rad2);
  b.hi[5] = std::log(o.max_heading_variance_rad2);
  return b;
}

Vector6 Clamp(const Vector6& x, const Box& box) { return x.cwiseMax(box.lo).cwiseMin(box.hi); }

// The starting point: a1..a4 in the prior shape at the common scale that minimises the
// objective (golden section on the log scale), the offsets at their prior centres.
template <typename F>
Vector6 Start(const F& f, const Box& box) {
  const MotionNoise& c = f.options.shape_prior;
  const std::array<double, 4> shape{std::log(c.a1), std::log(c.a2), std::log(c.a3), std::log(c.a4)};
  Vector6 x;
  x[4] = std::log(f.options.appearance_variance_prior_m2);
  x[5] = std::log(f.options.heading_variance_prior_rad2);
  auto at = [&](double scale) {
    Vector6 y = x;
    for (int j = 0; j < 4; ++j) y[j] = shape[j] + scale;
    return Clamp(y, box);
  };
  const double smallest = *std::min_element(shape.begin(), shape.end());
  const double largest = *std::max_element(shape.begin(), shape.end());
  double a = box.lo[0] - largest, b = box.hi[0] - smallest;
  constexpr double kInvPhi = 0.6180339887498949;
  double x1 = b - kInvPhi * (b - a), x2 = a + kInvPhi * (b - a);
  double f1 = f(at(x1)), f2 = f(at(x2));
  while (b - a > 1e-3) {
    if (f1 <= f2) {
      b = x2;
      x2 = x1;
      f2 = f1;
      x1 = b - kInvPhi * (b - a);
      f1 = f(at(x1));
    } else {
      a = x1;
      x1 = x2;
      f1 = f2;
      x2 = a + kInvPhi * (b - a);
      f2 = f(at(x2));
    }
  }
  return at(0.5 * (a + b));
}

// Fisher scoring on theta within the box, with a Levenberg-Marquardt damping that grows
// until a step lowers the objective; coordinates at a bound whose gradient points out of
// the box are held. Returns the estimate; `data` and `prior` are the curvatures there.
template <typename F>
Vector6 Fit(const F& f, const Box& box, int max_iterations, Matrix6* data, Matrix6* prior) {
  Vector6 x = Start(f, box);
  Vector6 g;
  double fx = f(x, &g, data, prior);
  double lambda = 1e-3;
  for (int it = 0; it < max_iterations && std::isfinite(fx); ++it) {
    const Matrix6 h = *data + *prior;
    std::array<bool, kP> free;
    for (int j = 0; j < kP; ++j) {
      free[j] = !((x[j] <= box.lo[j] && g[j] > 0) || (x[j] >= box.hi[j] && g[j] < 0));
    }
    bool accepted = false;
    Vector6 step = Vector6::Zero();
    for (int attempt = 0; attempt < 12 && !accepted; ++attempt) {
      Matrix6 a = Matrix6::Identity();
      Vector6 rhs = Vector6::Zero();
      for (int j = 0; j < kP; ++j) {
        if (!free[j]) continue;
        rhs[j] = -g[j];
        for (int l = 0; l < kP; ++l) {
          if (free[l]) a(j, l) = h(j, l);
        }
        a(j, j) += lambda * std::max(h(j, j), 1e-12) + 1e-12;
      }
      step = a.ldlt().solve(rhs);
      const Vector6 y = Clamp(x + step, box);
      Vector6 gy;
      Matrix6 dy, py;
      const double fy = f(y, &gy, &dy, &py);
      if (std::isfinite(fy) && fy < fx) {
        step = y - x;
        x = y;
        fx = fy;
        g = gy;
        *data = dy;
        *prior = py;
        lambda = std::max(lambda / 4.0, 1e-9);
        accepted = true;
      } else {
        lambda *= 8.0;
      }
    }
    if (!accepted || step.cwiseAbs().maxCoeff() < 1e-7) break;
  }
  return x;
}

double Median(std::vector<double> v) {
  const std::size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
  return v[mid];
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
  if (!(min_heading_variance_rad2 > 0 && min_heading_variance_rad2 < max_heading_variance_rad2 &&
        std::isfinite(max_heading_variance_rad2))) {
    fail("min_heading_variance_rad2/max_heading_variance_rad2", "0 < min < max");
  }
  for (double a : {shape_prior.a1, shape_prior.a2, shape_prior.a3, shape_prior.a4}) {
    if (!(a > 0 && std::isfinite(a))) fail("shape_prior", "a1..a4 > 0 and finite");
  }
  if (!(shape_prior_log_sd > 0 && std::isfinite(shape_prior_log_sd))) {
    fail("shape_prior_log_sd", "> 0");
  }
  if (!(appearance_variance_prior_m2 > 0 && std::isfinite(appearance_variance_prior_m2))) {
    fail("appearance_variance_prior_m2", "> 0");
  }
  if (!(heading_variance_prior_rad2 > 0 && std::isfinite(heading_variance_prior_rad2))) {
    fail("heading_variance_prior_rad2", "> 0");
  }
  if (!(offset_prior_log_sd > 0 && std::isfinite(offset_prior_log_sd))) {
    fail("offset_prior_log_sd", "> 0");
  }
  if (!(offset_dof >= 0 && std::isfinite(offset_dof))) fail("offset_dof", "finite and >= 0");
  if (!(outlier_confidence > 0 && outlier_confidence < 1)) fail("outlier_confidence", "in (0, 1)");
  if (min_pairs < 1) fail("min_pairs", ">= 1");
  if (max_iterations < 1) fail("max_iterations", ">= 1");
  if (max_rounds < 1) fail("max_rounds", ">= 1");
  if (joint_pairs < 0) fail("joint_pairs", ">= 0");
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
std::array<Eigen::Matrix3d, 4> Bases(const Prefixes& prefix, const std::vector<Pose2>& odometry,
                                     int s, int t) {
  std::array<Eigen::Matrix3d, 4> b;
  const Eigen::Vector2d c = Rotate90(odometry[t]);
  for (int j = 0; j < 4; ++j) b[j] = Evaluate(Minus(prefix[j][t], prefix[j][s]), c);
  return b;
}

// The covariance at pose t of a start error with covariance c0 at pose 0.
Eigen::Matrix3d StartCovarianceAt(const std::vector<Pose2>& poses, int t,
                                  const Eigen::Matrix3d& c0) {
  Eigen::Matrix3d phi = Eigen::Matrix3d::Identity();
  phi.block<2, 1>(0, 2) = Rotate90(poses[t]) - Rotate90(poses[0]);
  return phi * c0 * phi.transpose();
}

// The sessions' dead reckoning and its prefix sums, for the joint likelihood.
struct DeadReckoning {
  const std::vector<OdometrySession>& sessions;
  const std::vector<Prefixes>& prefixes;
};

// The covariance of the heading drifts of stretches a and b per unit a_j (added to
// `cross`) and from the start's heading variance (added to `start`): the heading noise of
// the steps both contain, sum s_i over the common steps; the heading is linear in the
// noise, so this is exact.
void AddHeadingCross(const Segment& a, const Segment& b, const DeadReckoning& dead,
                     std::array<double, 4>* cross, double* start) {
  if (a.session != b.session) return;
  const Prefixes& prefix = dead.prefixes[static_cast<std::size_t>(a.session)];
  const double sign = a.sign * b.sign;
  const int lo = std::max(std::max(a.from, b.from), 0);
  const int hi = std::min(a.to, b.to);
  if (hi > lo) {
    for (int j = 0; j < 4; ++j) (*cross)[j] += sign * (prefix[j][hi].s - prefix[j][lo].s);
  }
  if (a.from < 0 && b.from < 0) {
    *start += sign * dead.sessions[static_cast<std::size_t>(a.session)].start_covariance(2, 2);
  }
}

MotionNoiseIdentification Identify(const std::vector<Term>& terms, const DeadReckoning& dead,
                                   const MotionNoiseIdentificationOptions& options);

}  // namespace

std::vector<std::array<Eigen::Matrix3d, 4>> LoopDriftBases(const std::vector<Pose2>& odometry,
                                                           const std::vector<LoopPair>& pairs) {
  const int n = static_cast<int>(odometry.size());
  for (const LoopPair& p : pairs) {
    if (p.first < 0 || p.second >= n || p.first > p.second) {
      throw Error(StrCat("loop pair (", p.first, ", ", p.second, ") out of range or not ordered (",
                         n, " poses)"));
    }
  }
  const Prefixes prefix = BuildPrefixes(odometry);
  std::vector<std::array<Eigen::Matrix3d, 4>> out(pairs.size());
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
    if (p.heading_rad && !std::isfinite(*p.heading_rad)) {
      throw Error(StrCat("loop pair (", p.first_session, ":", p.first, ", ", p.second_session, ":",
                         p.second, ") has a non-finite heading"));
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
    Term& term = terms[k];
    term.r.head<2>() = Eigen::Vector2d(pb.x() - pa.x(), pb.y() - pa.y());
    if (p.heading_rad) {
      term.dim = 3;
      term.r[2] = WrapAngle(pb.z() - pa.z() - *p.heading_rad);
    }
    if (p.first_session == p.second_session) {
      term.b = Bases(prefixes[p.first_session], a.poses, p.first, p.second);
      term.segments[0] = Segment{p.first_session, p.first, p.second, 1.0};
    } else {
      term.segment_count = 2;
      term.segments[0] = Segment{p.second_session, -1, p.second, 1.0};
      term.segments[1] = Segment{p.first_session, -1, p.first, -1.0};
      const auto ba = Bases(prefixes[p.first_session], a.poses, 0, p.first);
      const auto bb = Bases(prefixes[p.second_session], b.poses, 0, p.second);
      for (int j = 0; j < 4; ++j) term.b[j] = ba[j] + bb[j];
      term.fixed = StartCovarianceAt(a.poses, p.first, a.start_covariance) +
                   StartCovarianceAt(b.poses, p.second, b.start_covariance);
    }
  }
  return Identify(terms, DeadReckoning{sessions, prefixes}, options);
}

MotionNoiseIdentification IdentifyMotionNoise(const std::vector<Pose2>& odometry,
                                              const std::vector<LoopPair>& pairs,
                                              const MotionNoiseIdentificationOptions& options) {
  OdometrySession session;
  session.poses = odometry;
  std::vector<SessionLoopPair> session_pairs;
  for (const LoopPair& p : pairs) {
    session_pairs.push_back(SessionLoopPair{0, p.first, 0, p.second, p.heading_rad});
  }
  return IdentifyMotionNoise({session}, session_pairs, options);
}

namespace {

// The joint likelihood of the heading innovations of a set of pairs (3-dof pairs): stacked
// into one vector z,
//   z ~ N(0, S),  S = F + sum_j a_j A_j + rho_phi I,
// where A_j(u, w) is the covariance of pair u's and pair w's heading drift over the steps
// their stretches of dead reckoning share, per unit a_j (the pairs of one revisit, and
// of every revisit of one stretch, share almost all of them), F the start headings'
// variance, and rho_phi the descriptor's relative-heading noise (independent per pair).
// The heading is linear in the noise, so S is exact (while a pair's drift stays within
// half a turn, where WrapAngle keeps the innovation unwrapped); the xy innovations are not
// used here:
// they carry the heading drift over the loop on lever arms of the loop's size, where the
// linearisation about the dead reckoning fails once the drift reaches tenths of a radian.
// rho enters only through its prior.
class HeadingJointObjective {
 public:
  HeadingJointObjective(const std::vector<Term>& terms, const std::vector<std::size_t>& chosen,
                        const DeadReckoning& dead, const MotionNoiseIdentificationOptions& opts)
      : options(opts) {
    const int n = static_cast<int>(chosen.size());
    z_.resize(n);
    fixed_.setZero(n, n);
    for (auto& a : a_) a.setZero(n, n);
    for (int u = 0; u < n; ++u) {
      const Term& tu = terms[chosen[u]];
      z_[u] = tu.r[2];
      for (int w = u; w < n; ++w) {
        const Term& tw = terms[chosen[w]];
        std::array<double, 4> cross{};
        double start = 0.0;
        for (int i = 0; i < tu.segment_count; ++i) {
          for (int l = 0; l < tw.segment_count; ++l) {
            AddHeadingCross(tu.segments[i], tw.segments[l], dead, &cross, &start);
          }
        }
        for (int j = 0; j < 4; ++j) a_[j](u, w) = a_[j](w, u) = cross[j];
        fixed_(u, w) = fixed_(w, u) = start;
      }
    }
  }

  // -2 ln posterior of theta (up to constants); with g, its gradient, the pairs' Fisher
  // information (`data`) and the prior's Hessian, as Objective.
  double operator()(const Vector6& theta, Vector6* g = nullptr, Matrix6* data = nullptr,
                    Matrix6* prior = nullptr) const {
    const Vector6 v = theta.array().exp();
    const Eigen::Index n = z_.size();
    Eigen::MatrixXd s = fixed_;
    for (int j = 0; j < 4; ++j) s += v[j] * a_[j];
    s.diagonal().array() += v[kPhi];
    const Eigen::LLT<Eigen::MatrixXd> llt(s);
    if (llt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
    const Eigen::VectorXd alpha = llt.solve(z_);
    const double sum = 2.0 * llt.matrixLLT().diagonal().array().log().sum() + z_.dot(alpha);
    if (!std::isfinite(sum)) return std::numeric_limits<double>::infinity();
    if (g != nullptr) {
      g->setZero();
      data->setZero();
      prior->setZero();
      // g_j = v_j (tr(S^-1 A_j) - alpha^T A_j alpha), F_jl = v_j v_l tr(S^-1 A_j S^-1 A_l),
      // with A_phi = I; rho has no term here.
      const Eigen::MatrixXd si = llt.solve(Eigen::MatrixXd::Identity(n, n));
      std::array<Eigen::MatrixXd, 5> m;
      for (int j = 0; j < 4; ++j) m[j] = si * a_[j];
      m[4] = si;
      std::array<int, 5> index{0, 1, 2, 3, kPhi};
      for (int j = 0; j < 5; ++j) {
        const double quadratic = j < 4 ? alpha.dot(a_[j] * alpha) : alpha.squaredNorm();
        (*g)[index[j]] = v[index[j]] * (m[j].trace() - quadratic);
        for (int l = j; l < 5; ++l) {
          const double x =
              v[index[j]] * v[index[l]] * (m[j].array() * m[l].transpose().array()).sum();
          (*data)(index[j], index[l]) = x;
          (*data)(index[l], index[j]) = x;
        }
      }
    }
    return sum + AddPrior(theta, options, g, prior);
  }

  const MotionNoiseIdentificationOptions& options;

 private:
  static constexpr int kPhi = static_cast<int>(IdentifiedParameter::kHeadingVariance);
  Eigen::VectorXd z_;
  Eigen::MatrixXd fixed_;
  std::array<Eigen::MatrixXd, 4> a_;
};

// The posterior sd of the logarithm of parameters first..last - 1, from the covariance of
// theta (the inverse of half the -2 ln posterior's curvature), and the data's share of
// their curvature; the other parameters' entries of `result` stay.
void SetUncertainty(const Matrix6& data, const Matrix6& prior, int first, int last,
                    MotionNoiseIdentification* result) {
  const Matrix6 covariance =
      (0.5 * (data + prior)).completeOrthogonalDecomposition().pseudoInverse();
  for (int j = first; j < last; ++j) {
    result->log_sd[j] = std::sqrt(std::max(covariance(j, j), 0.0));
    const double total = data(j, j) + prior(j, j);
    result->data_share[j] = total > 0 ? data(j, j) / total : 0.0;
  }
}

MotionNoiseIdentification Identify(const std::vector<Term>& terms, const DeadReckoning& dead,
                                   const MotionNoiseIdentificationOptions& options) {
  MotionNoiseIdentification result;
  result.pairs = static_cast<int>(terms.size());
  if (result.pairs < options.min_pairs) return result;

  const Box box = Bounds(options);
  std::vector<char> use(terms.size(), 1);
  const Objective objective{terms, use, options};
  Matrix6 data, prior;
  std::array<double, 4> gate;
  for (int dim = 2; dim <= 3; ++dim) gate[dim] = ChiSquareQuantile(options.outlier_confidence, dim);
  for (int round = 0; round < options.max_rounds; ++round) {
    const Vector6 v = Fit(objective, box, options.max_iterations, &data, &prior).array().exp();
    // Each NIS relative to the chi-square median of its dof, scaled so that the median of
    // the pairs in use is 1: while aliases inflate the fit, the inliers' NIS are uniformly
    // too small, and the scaling (robust to a minority of aliases) restores the gate's
    // meaning.
    std::vector<double> ratio;
    for (std::size_t k = 0; k < terms.size(); ++k) {
      if (use[k]) ratio.push_back(Nis(terms[k], v) / kChiSquareMedian[terms[k].dim]);
    }
    if (ratio.empty()) break;
    const double median = Median(ratio);
    const double scale = median > 0 ? 1.0 / median : 1.0;
    std::vector<char> next(terms.size(), 0);
    for (std::size_t k = 0; k < terms.size(); ++k) {
      next[k] = scale * Nis(terms[k], v) <= gate[terms[k].dim];
    }
    if (next == use) break;
    use = std::move(next);
  }
  // The final fit starts from the same point as every fit, so the estimate depends on the
  // inlier set only, not on the path of the rejection rounds.
  const Vector6 theta = Fit(objective, box, options.max_iterations, &data, &prior);
  const Vector6 v = theta.array().exp();
  std::vector<double> ratio;
  double per_dof = 0.0;
  for (std::size_t k = 0; k < terms.size(); ++k) {
    if (!use[k]) continue;
    const double nis = Nis(terms[k], v);
    ratio.push_back(nis / kChiSquareMedian[terms[k].dim]);
    per_dof += nis / terms[k].dim;
    if (terms[k].dim == 3) ++result.pairs_with_heading;
  }
  result.pairs_used = static_cast<int>(ratio.size());
  if (result.pairs_used < options.min_pairs) return result;
  result.identified = true;
  result.noise = MotionNoise{v[0], v[1], v[2], v[3]};
  result.appearance_variance_m2 = v[4];
  result.heading_variance_rad2 = v[5];
  result.median_nis_ratio = Median(ratio);
  result.mean_nis_per_dof = per_dof / static_cast<double>(ratio.size());
  SetUncertainty(data, prior, 0, kP, &result);
  if (options.offset_dof > 0) {
    // The offset from the same inliers under the Student t: the core of the offsets, not
    // their second moment (the header; docs/design.md).
    const Objective robust{terms, use, options, options.offset_dof};
    Matrix6 robust_data, robust_prior;
    constexpr int kRho = static_cast<int>(IdentifiedParameter::kAppearanceVariance);
    const Vector6 theta_t = Fit(robust, box, options.max_iterations, &robust_data, &robust_prior);
    result.appearance_variance_m2 = std::exp(theta_t[kRho]);
    SetUncertainty(robust_data, robust_prior, kRho, kRho + 1, &result);
  }
  if (options.joint_pairs > 0) {
    // a1..a4 from the joint likelihood of the heading innovations of up to joint_pairs
    // inliers with heading, evenly spaced in the order given (the header; docs/design.md).
    std::vector<std::size_t> with_heading;
    for (std::size_t k = 0; k < terms.size(); ++k) {
      if (use[k] && terms[k].dim == 3) with_heading.push_back(k);
    }
    const std::size_t m =
        std::min(with_heading.size(), static_cast<std::size_t>(options.joint_pairs));
    if (m >= static_cast<std::size_t>(options.min_pairs)) {
      std::vector<std::size_t> chosen;
      for (std::size_t i = 0; i < m; ++i) {
        chosen.push_back(with_heading[i * with_heading.size() / m]);
      }
      const HeadingJointObjective joint(terms, chosen, dead, options);
      Matrix6 joint_data, joint_prior;
      const Vector6 theta_j = Fit(joint, box, options.max_iterations, &joint_data, &joint_prior);
      if (std::isfinite(joint(theta_j))) {
        const Vector6 vj = theta_j.array().exp();
        result.noise = MotionNoise{vj[0], vj[1], vj[2], vj[3]};
        result.joint_pairs_used = static_cast<int>(chosen.size());
        SetUncertainty(joint_data, joint_prior, 0, 4, &result);
      }
    }
  }
  return result;
}

}  // namespace

}  // namespace omnicml
