#include "omnicml/geometry/gaussian_mixture.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "omnicml/common/common.h"

namespace omnicml {

double SquaredMahalanobis(const Pose2& a, const Pose2& b, const Eigen::Matrix3d& s) {
  if (!s.allFinite()) throw Error("SquaredMahalanobis: the covariance has NaN/inf entries");
  const Eigen::LLT<Eigen::Matrix3d> llt(s);
  if (llt.info() != Eigen::Success) {
    throw Error("SquaredMahalanobis: the covariance is not symmetric positive definite");
  }
  const Eigen::Vector3d d = PoseDifference(a, b);
  // d^T S^-1 d = |L^-1 d|^2 with S = L L^T; never negative.
  return llt.matrixL().solve(d).squaredNorm();
}

double LargestEigenvalue2(const Eigen::Matrix2d& m) {
  const double half_trace = 0.5 * (m(0, 0) + m(1, 1));
  const double half_diff = 0.5 * (m(0, 0) - m(1, 1));
  return half_trace + std::sqrt(half_diff * half_diff + m(0, 1) * m(1, 0));
}

Eigen::Matrix3d RepairCovariance(const Eigen::Matrix3d& c, double min_eigenvalue,
                                 const std::string& what) {
  if (!c.allFinite()) throw Error(StrCat(what, ": has NaN/inf entries"));
  const double scale = c.cwiseAbs().maxCoeff();
  const double asymmetry = (c - c.transpose()).cwiseAbs().maxCoeff();
  if (asymmetry > 1e-6 * scale) {
    throw Error(StrCat(what, ": is not symmetric (largest |C - C^T| entry ", asymmetry,
                       ", largest |C| entry ", scale, ")"));
  }
  const Eigen::Matrix3d sym = 0.5 * (c + c.transpose());
  // Fast path for the common, well-conditioned case: the closed-form eigenvalues are
  // accurate to ~1e-12 of the largest one, so a smallest eigenvalue well above that
  // bound and above min_eigenvalue means nothing needs repairing.
  {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> direct;
    direct.computeDirect(sym, Eigen::EigenvaluesOnly);
    const Eigen::Vector3d l = direct.eigenvalues();
    if (l.allFinite() && l(0) > 1e-8 * l.cwiseAbs().maxCoeff() && l(0) > 2.0 * min_eigenvalue)
      return sym;
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(sym);
  if (eig.info() != Eigen::Success) throw Error(StrCat(what, ": eigen decomposition failed"));
  const Eigen::Vector3d lambda = eig.eigenvalues();  // ascending
  const double largest = lambda.cwiseAbs().maxCoeff();
  if (lambda(0) < -1e-6 * largest) {
    throw Error(StrCat(what, ": is not positive semi-definite (eigenvalues ", lambda(0), ", ",
                       lambda(1), ", ", lambda(2), ")"));
  }
  if (lambda(0) >= min_eigenvalue) return sym;
  const Eigen::Vector3d clamped = lambda.cwiseMax(min_eigenvalue);
  const Eigen::Matrix3d v = eig.eigenvectors();
  const Eigen::Matrix3d repaired = v * clamped.asDiagonal() * v.transpose();
  return 0.5 * (repaired + repaired.transpose());
}

Gaussian MomentMatch(std::span<const Gaussian> components, HeadingMean heading) {
  if (components.empty()) throw Error("MomentMatch: no components");
  if (components.size() == 1) return components.front();
  double total = 0.0, sum_x = 0.0, sum_y = 0.0, sum_sin = 0.0, sum_cos = 0.0;
  for (const Gaussian& g : components) {
    if (!(std::isfinite(g.weight) && g.weight >= 0)) {
      throw Error(StrCat("MomentMatch: component weight must be finite and >= 0, got ", g.weight));
    }
    total += g.weight;
    sum_x += g.weight * g.mean.x();
    sum_y += g.weight * g.mean.y();
    sum_sin += g.weight * std::sin(g.mean.z());
    sum_cos += g.weight * std::cos(g.mean.z());
  }
  if (!(total > 0)) throw Error("MomentMatch: the weights sum to zero");
  Gaussian out;
  out.weight = total;
  if (heading == HeadingMean::kCircular) {
    // [G] (13) with the circular mean for the heading: either side of +-pi averages to pi.
    out.mean = MakePose(sum_x / total, sum_y / total, std::atan2(sum_sin, sum_cos));
  } else {
    // [G] (13) anchored at the first mean: mean_0 + sum_i (w_i / total) (mean_i - mean_0),
    // differences wrapped.
    const Pose2& anchor = components.front().mean;
    Eigen::Vector3d step = Eigen::Vector3d::Zero();
    for (std::size_t i = 1; i < components.size(); ++i) {
      step += (components[i].weight / total) * PoseDifference(components[i].mean, anchor);
    }
    out.mean = MakePose(anchor.x() + step.x(), anchor.y() + step.y(), anchor.z() + step.z());
  }
  // [G] (14): C = sum_i w_i (C_i + d_i d_i^T) / sum_i w_i with d_i wrapped.
  Eigen::Matrix3d c = Eigen::Matrix3d::Zero();
  for (const Gaussian& g : components) {
    const Eigen::Vector3d d = PoseDifference(g.mean, out.mean);
    c += (g.weight / total) * (g.covariance + d * d.transpose());
  }
  out.covariance = 0.5 * (c + c.transpose());
  return out;
}

Gaussian CombineInformation(const Gaussian& a, const Eigen::Matrix3d& info_a, double share_a,
                            const Gaussian& b, const Eigen::Matrix3d& info_b, double share_b,
                            double min_eigenvalue, const char* what) {
  const Eigen::Matrix3d information = share_a * info_a + share_b * info_b;
  const Eigen::LLT<Eigen::Matrix3d> llt(information);
  if (llt.info() != Eigen::Success) {
    throw Error(StrCat(what, ": the fused information matrix is not positive definite (shares ",
                       share_a, ", ", share_b, ")"));
  }
  Gaussian out;
  // The tracker fuses many pairs per frame: the message is composed only on failure.
  static const std::string kFused = "fused covariance";
  try {
    out.covariance =
        RepairCovariance(llt.solve(Eigen::Matrix3d::Identity()), min_eigenvalue, kFused);
  } catch (const Error& e) {
    throw Error(StrCat(what, ": ", e.what()));
  }
  // C (share_a I_a mu_a + share_b I_b (mu_a + d)) = mu_a + C share_b I_b d.
  const Eigen::Vector3d d = PoseDifference(b.mean, a.mean);
  const Eigen::Vector3d shift = llt.solve(share_b * (info_b * d));
  out.mean = MakePose(a.mean.x() + shift.x(), a.mean.y() + shift.y(), a.mean.z() + shift.z());
  out.weight = 0.0;
  return out;
}

Gaussian CovarianceIntersection(const Gaussian& a, const Gaussian& b, double omega) {
  if (!(omega >= 0 && omega <= 1))
    throw Error(StrCat("CovarianceIntersection: omega must be in [0, 1], got ", omega));
  static const std::string kA = "CovarianceIntersection: C_a", kB = "CovarianceIntersection: C_b";
  const Eigen::Matrix3d ca = RepairCovariance(a.covariance, 1e-12, kA);
  const Eigen::Matrix3d cb = RepairCovariance(b.covariance, 1e-12, kB);
  return CombineInformation(a, ca.inverse(), 1.0 - omega, b, cb.inverse(), omega, 1e-12,
                            "CovarianceIntersection");
}

Eigen::Matrix3d LinearCombinationBound(const Eigen::Matrix3d& c_a, double share_a,
                                       const Eigen::Matrix3d& c_b, double share_b) {
  if (!(share_a >= 0 && share_b >= 0 && share_a + share_b > 0)) {
    throw Error(StrCat("LinearCombinationBound: shares must be >= 0 and not both 0, got ", share_a,
                       ", ", share_b));
  }
  const Eigen::Matrix3d a = share_a * share_a * c_a;
  const Eigen::Matrix3d b = share_b * share_b * c_b;
  if (share_b == 0) return a;
  if (share_a == 0) return b;
  const auto member = [&](double log_k) {
    const double k = std::exp(log_k);
    return Eigen::Matrix3d((1.0 + k) * a + (1.0 + 1.0 / k) * b);
  };
  // Golden-section search on t = log k, where log det is convex (with lambda_i the
  // eigenvalues of b^-1 a, det = ((1 + k) / k)^3 det(b) prod (1 + k lambda_i), a sum of
  // log-sum-exp terms in t). t in [-40, 40] spans k from 4e-18 to 2e17, beyond any ratio
  // of shares and covariances a map holds.
  constexpr double kInvPhi = 0.6180339887498949;
  double lo = -40.0, hi = 40.0;
  double x1 = hi - kInvPhi * (hi - lo), x2 = lo + kInvPhi * (hi - lo);
  double f1 = member(x1).determinant(), f2 = member(x2).determinant();
  for (int i = 0; i < 100; ++i) {
    if (f1 <= f2) {
      hi = x2;
      x2 = x1;
      f2 = f1;
      x1 = hi - kInvPhi * (hi - lo);
      f1 = member(x1).determinant();
    } else {
      lo = x1;
      x1 = x2;
      f1 = f2;
      x2 = lo + kInvPhi * (hi - lo);
      f2 = member(x2).determinant();
    }
  }
  const Eigen::Matrix3d c = member(0.5 * (lo + hi));
  return 0.5 * (c + c.transpose());
}

double TotalWeight(const Mixture& m) {
  double total = 0.0;
  for (const Gaussian& g : m) total += g.weight;
  return total;
}

void NormalizeWeights(Mixture* m) {
  const double total = TotalWeight(*m);
  if (m->empty() || !(total > 0) || !std::isfinite(total)) return;
  for (Gaussian& g : *m) g.weight /= total;
}

int StrongestComponent(const Mixture& m) {
  int best = -1;
  for (int i = 0; i < static_cast<int>(m.size()); ++i) {
    if (best < 0 || m[i].weight > m[best].weight) best = i;
  }
  return best;
}

}  // namespace omnicml
