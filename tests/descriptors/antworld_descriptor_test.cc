// Place recognition and heading on real, externally produced panoramas: the AntWorld
// subset in ../shared/datasets/antworld (see its README). Route frames are matched to
// the Fourier-nearest grid view; the match should lie near the true position, and the
// relative heading to that (heading-0) grid view should equal the pose file's heading.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "omnicml/common/common.h"
#include "omnicml/descriptors/fourier_signature.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

const fs::path kDataDir = fs::path(OMNICML_SOURCE_DIR) / ".." / "shared" / "datasets" / "antworld";

struct View {
  double x_m = 0, y_m = 0, heading_deg = 0;
  std::string file;
};

// Reads "X [mm], Y [mm], Z [mm], Heading [degrees], Filename" rows (one header line).
std::vector<View> ReadPoses(const fs::path& csv) {
  std::ifstream in(csv);
  if (!in) throw Error(StrCat("cannot open ", csv.string()));
  std::vector<View> views;
  std::string line;
  std::getline(in, line);  // header
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    std::stringstream ss(line);
    std::string field;
    std::vector<std::string> fields;
    while (std::getline(ss, field, ',')) fields.push_back(field);
    if (fields.size() != 5) throw Error(StrCat(csv.string(), ":", line_no, ": expected 5 fields"));
    View v;
    v.x_m = std::stod(fields[0]) / 1000.0;
    v.y_m = std::stod(fields[1]) / 1000.0;
    v.heading_deg = std::stod(fields[3]);
    const auto b = fields[4].find_first_not_of(" \t"), e = fields[4].find_last_not_of(" \t\r");
    v.file = (csv.parent_path() / fields[4].substr(b, e - b + 1)).string();
    views.push_back(v);
  }
  return views;
}

double Percentile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(std::clamp(p * (v.size() - 1), 0.0, v.size() - 1.0));
  return v[i];
}

struct Figures {
  int frames = 0;
  double fraction_within = 0;                          // nearest grid view within 0.5 m
  double heading_median_deg = 0, heading_p90_deg = 0;  // frames matched within 0.5 m
  double all_heading_median_deg = 0;                   // all frames
  double flipped_median_deg = 0;  // matched frames, with the opposite sign convention
};

// Matches every 4th route frame against the grid with one Fourier configuration.
Figures Evaluate(const FourierOptions& options, const std::vector<View>& grid,
                 const std::vector<cv::Mat>& grid_images, const std::vector<View>& route,
                 const std::vector<cv::Mat>& route_images) {
  const FourierSignature extractor(options);
  std::vector<Descriptor> grid_descriptors;
  for (const auto& image : grid_images) grid_descriptors.push_back(extractor.Compute(image));
  Figures f;
  int within = 0;
  std::vector<double> matched_error, flipped_error, all_error;
  for (std::size_t i = 0; i < route.size(); ++i) {
    const Descriptor d = extractor.Compute(route_images[i]);
    std::size_t best = 0;
    double best_distance = 1e300;
    for (std::size_t j = 0; j < grid.size(); ++j) {
      const double e = extractor.Distance(d, grid_descriptors[j]);
      if (e < best_distance) best_distance = e, best = j;
    }
    ++f.frames;
    // Heading of the route frame minus heading 0 of the grid view.
    const auto rel = extractor.RelativeHeading(d, grid_descriptors[best]);
    if (!rel) throw Error("no heading from a textured AntWorld view");
    const double truth = route[i].heading_deg * kPi / 180.0;
    const double error = std::fabs(WrapAngle(*rel - truth)) * 180.0 / kPi;
    all_error.push_back(error);
    if (std::hypot(route[i].x_m - grid[best].x_m, route[i].y_m - grid[best].y_m) <= 0.5) {
      ++within;
      matched_error.push_back(error);
      flipped_error.push_back(std::fabs(WrapAngle(-*rel - truth)) * 180.0 / kPi);
    }
  }
  f.fraction_within = static_cast<double>(within) / f.frames;
  if (!matched_error.empty()) {
    f.heading_median_deg = Percentile(matched_error, 0.5);
    f.heading_p90_deg = Percentile(matched_error, 0.9);
    f.flipped_median_deg = Percentile(flipped_error, 0.5);
  }
  f.all_heading_median_deg = Percentile(all_error, 0.5);
  return f;
}

// For every 4th route frame, the Fourier-nearest grid view lies within 0.5 m for at least
// a measured fraction of frames, and for those frames the relative heading to that
// (heading-0) grid view matches the pose file's heading: in the raw files, the heading
// and the image columns turn the same way (both clockwise, see antworld.h, whose reader
// converts both to our counter-clockwise convention), so on raw images
// RelativeHeading(route frame, grid view) = +heading (the opposite sign is far off).
TEST(AntWorld, FourierNearestGridViewAndHeading) {
  const fs::path route_csv = kDataDir / "ant1_route1" / "ant1_route1.csv";
  const fs::path grid_csv = kDataDir / "grid_200mm" / "grid_200mm.csv";
  if (!fs::exists(route_csv) || !fs::exists(grid_csv)) {
    GTEST_SKIP() << "AntWorld data not found under " << kDataDir.string()
                 << " (expected ant1_route1/ant1_route1.csv and grid_200mm/grid_200mm.csv)";
  }
  const std::vector<View> grid = ReadPoses(grid_csv);
  const std::vector<View> all_route = ReadPoses(route_csv);
  ASSERT_GT(grid.size(), 100u);
  ASSERT_GT(all_route.size(), 100u);
  auto read = [](const View& v) {
    cv::Mat image = cv::imread(v.file, cv::IMREAD_COLOR);
    if (image.empty()) throw Error(StrCat("cannot read ", v.file));
    return image;
  };
  std::vector<cv::Mat> grid_images, route_images;
  std::vector<View> route;
  for (const auto& v : grid) grid_images.push_back(read(v));
  for (std::size_t i = 0; i < all_route.size(); i += 4) {
    route.push_back(all_route[i]);
    route_images.push_back(read(all_route[i]));
  }

  struct Case {
    const char* name;
    FourierOptions options;
    double min_fraction;    // measured fraction minus a margin
    double max_median_deg;  // measured median plus a margin
    double max_p90_deg;     // measured 90th percentile plus a margin
  };
  FourierOptions bands_only;
  bands_only.normalize_columns = false;
  FourierOptions raw;
  raw.normalize_bands = false;
  raw.normalize_columns = false;
  const Case cases[] = {
      // Measured (every 4th frame, 203 frames): 0.404 within 0.5 m; heading error
      // median 1.64 deg, p90 8.3 deg. Column normalisation, which buys robustness to
      // light zones indoors, costs place discrimination in this outdoor world of constant
      // light, where each column's brightness (the skyline) is itself place information.
      {"default (4 bands x 16, columns and bands normalised, L2)", FourierOptions{}, 0.38, 2.2,
       10.5},
      // Measured: 0.473 within 0.5 m; median 2.08 deg, p90 11.5 deg.
      {"bands normalised, columns not", bands_only, 0.45, 2.6, 13.0},
      // Measured: 0.547 within 0.5 m (the DC term carries place information in this
      // single-condition world); median 2.10 deg, p90 15.2 deg.
      {"not normalised (DC kept)", raw, 0.52, 2.6, 17.0},
  };
  for (const Case& c : cases) {
    const Figures f = Evaluate(c.options, grid, grid_images, route, route_images);
    std::cout << "[ AntWorld ] " << c.name << ": " << f.frames
              << " frames, nearest grid view within 0.5 m for " << f.fraction_within
              << "; heading error on those: median " << f.heading_median_deg << " deg, p90 "
              << f.heading_p90_deg << " deg (opposite sign: median " << f.flipped_median_deg
              << " deg); all frames: median " << f.all_heading_median_deg << " deg\n";
    EXPECT_GE(f.fraction_within, c.min_fraction) << c.name;
    EXPECT_LE(f.heading_median_deg, c.max_median_deg) << c.name;
    EXPECT_LE(f.heading_p90_deg, c.max_p90_deg) << c.name;
    EXPECT_GT(f.flipped_median_deg, 15.0) << c.name;  // measured 28.5 and 25.4 deg
  }
}

}  // namespace
}  // namespace omnicml
