#include "unwrap/internal/circle_fit.h"

#include <algorithm>
#include <cmath>
#include <memory>

#include <ceres/ceres.h>

#include "omnicml/common/common.h"

namespace omnicml::internal {
namespace {

// Geometric distance of one point to a circle: |p - c| - r. Parameters: centre (2), radius (1).
struct CircleResidual {
  CircleResidual(double x, double y) : x_(x), y_(y) {}
  template <typename T>
  bool operator()(const T* const center, const T* const radius, T* residual) const {
    const T dx = T(x_) - center[0];
    const T dy = T(y_) - center[1];
    // Guard the derivative of sqrt at 0 (a point exactly on the centre).
    const T d2 = dx * dx + dy * dy + T(1e-12);
    residual[0] = ceres::sqrt(d2) - radius[0];
    return true;
  }
  double x_, y_;
};

double Median(std::vector<double> v) {
  OMNICML_CHECK(!v.empty());
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

}  // namespace

CircleFitReport FitConcentricCircles(const std::vector<std::vector<cv::Point2d>>& sets,
                                     const ConcentricCircles& initial, RobustLoss loss,
                                     double loss_scale_px, double min_inlier_threshold_px) {
  OMNICML_CHECK(!sets.empty());
  OMNICML_CHECK(initial.radii_px.size() == sets.size());
  OMNICML_CHECK(loss_scale_px > 0.0) << "loss_scale_px=" << loss_scale_px;

  double center[2] = {initial.center_px.x, initial.center_px.y};
  std::vector<double> radii = initial.radii_px;

  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  std::unique_ptr<ceres::LossFunction> loss_function;
  if (loss == RobustLoss::kHuber) loss_function = std::make_unique<ceres::HuberLoss>(loss_scale_px);
  if (loss == RobustLoss::kCauchy)
    loss_function = std::make_unique<ceres::CauchyLoss>(loss_scale_px);
  problem.AddParameterBlock(center, 2);
  for (std::size_t s = 0; s < sets.size(); ++s) {
    OMNICML_CHECK(sets[s].size() >= 3) << "set " << s << " has " << sets[s].size() << " points";
    problem.AddParameterBlock(&radii[s], 1);
    for (const cv::Point2d& p : sets[s]) {
      auto* cost =
          new ceres::AutoDiffCostFunction<CircleResidual, 1, 2, 1>(new CircleResidual(p.x, p.y));
      problem.AddResidualBlock(cost, loss_function.get(), center, &radii[s]);
    }
  }
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = 100;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  options.minimizer_progress_to_stdout = false;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);

  CircleFitReport report;
  report.circles.center_px = cv::Point2d(center[0], center[1]);
  report.circles.radii_px = radii;
  for (std::size_t s = 0; s < sets.size(); ++s) {
    std::vector<double> abs_residuals;
    abs_residuals.reserve(sets[s].size());
    for (const cv::Point2d& p : sets[s]) {
      abs_residuals.push_back(std::abs(std::hypot(p.x - center[0], p.y - center[1]) - radii[s]));
    }
    const double mad = Median(abs_residuals);
    const double threshold = std::max(min_inlier_threshold_px, 3.0 * 1.4826 * mad);
    std::vector<char> is_inlier(sets[s].size(), 0);
    double sum_sq = 0.0;
    int count = 0;
    for (std::size_t i = 0; i < abs_residuals.size(); ++i) {
      if (abs_residuals[i] <= threshold) {
        is_inlier[i] = 1;
        sum_sq += abs_residuals[i] * abs_residuals[i];
        ++count;
      }
    }
    report.rms_px.push_back(count > 0 ? std::sqrt(sum_sq / count) : 0.0);
    report.inliers.push_back(count);
    report.is_inlier.push_back(std::move(is_inlier));
  }
  return report;
}

}  // namespace omnicml::internal
