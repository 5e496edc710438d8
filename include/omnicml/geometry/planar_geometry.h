// Small 2-D geometry helpers (segments, polygons) shared by the simulator and the baselines.
#ifndef OMNICML_GEOMETRY_PLANAR_GEOMETRY_H_
#define OMNICML_GEOMETRY_PLANAR_GEOMETRY_H_

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Core>

namespace omnicml::geometry {

// Distance of p to the segment a-b, metres.
inline double DistancePointSegment(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                                   const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

inline double Cross(const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return a.x() * b.y() - a.y() * b.x();
}

// True when the closed segments a-b and c-d intersect (proper or touching).
inline bool SegmentsIntersect(const Eigen::Vector2d& a, const Eigen::Vector2d& b,
                              const Eigen::Vector2d& c, const Eigen::Vector2d& d) {
  const double d1 = Cross(b - a, c - a), d2 = Cross(b - a, d - a);
  const double d3 = Cross(d - c, a - c), d4 = Cross(d - c, b - c);
  if (((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0)))
    return true;
  const auto on = [](const Eigen::Vector2d& p, const Eigen::Vector2d& q, const Eigen::Vector2d& r) {
    return std::min(p.x(), q.x()) <= r.x() && r.x() <= std::max(p.x(), q.x()) &&
           std::min(p.y(), q.y()) <= r.y() && r.y() <= std::max(p.y(), q.y());
  };
  if (d1 == 0 && on(a, b, c)) return true;
  if (d2 == 0 && on(a, b, d)) return true;
  if (d3 == 0 && on(c, d, a)) return true;
  if (d4 == 0 && on(c, d, b)) return true;
  return false;
}

// Even-odd rule; points on the boundary may go either way.
inline bool PointInPolygon(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& p) {
  bool inside = false;
  for (std::size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
    const Eigen::Vector2d& a = poly[i];
    const Eigen::Vector2d& b = poly[j];
    if ((a.y() > p.y()) != (b.y() > p.y())) {
      const double x = a.x() + (p.y() - a.y()) * (b.x() - a.x()) / (b.y() - a.y());
      if (p.x() < x) inside = !inside;
    }
  }
  return inside;
}

}  // namespace omnicml::geometry

#endif  // OMNICML_GEOMETRY_PLANAR_GEOMETRY_H_
