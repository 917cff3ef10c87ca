// Smoothed field derivatives, safety masks and margins, rasterised scenes, clearance, save/load.
#include <gtest/gtest.h>

#include <unistd.h>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include "terrastride/perception/npy.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride::terrain;

namespace {

GridGeometry geometry(int nx, int ny, double res = 0.02) {
  GridGeometry g;
  g.origin = Eigen::Vector2d(-0.3, 0.1);
  g.resolution = res;
  g.nx = nx;
  g.ny = ny;
  return g;
}

std::vector<float> random_values(const GridGeometry& g, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-0.1f, 0.1f);
  std::vector<float> v(g.size());
  for (auto& x : v) x = u(rng);
  return v;
}

// Central differences of value -> gradient and gradient -> Hessian at (x, y).
void check_derivatives(const BSplineField& f, double x, double y) {
  const double e = 1e-6;
  const HeightSample s = f.sample(x, y);
  const double gx = (f.value(x + e, y) - f.value(x - e, y)) / (2 * e);
  const double gy = (f.value(x, y + e) - f.value(x, y - e)) / (2 * e);
  // Tolerances relative to the field's scale: values ~0.1 m over 0.02 m cells give gradients ~10
  // and Hessians ~1e3, so FD errors are ~1e-6 relative.
  EXPECT_NEAR(s.gradient.x(), gx, 1e-5 * (1 + std::abs(gx))) << x << "," << y;
  EXPECT_NEAR(s.gradient.y(), gy, 1e-5 * (1 + std::abs(gy))) << x << "," << y;
  Eigen::Vector2d g;
  EXPECT_NEAR(f.value_gradient(x, y, &g), s.height, 1e-12);
  EXPECT_NEAR((g - s.gradient).norm(), 0.0, 1e-9);
  // The planner's height and gradient without the Hessian: sample()'s to the bit (plans depend on it).
  Eigen::Vector2d g_exact;
  EXPECT_EQ(f.sample_value_gradient(x, y, &g_exact), s.height) << x << "," << y;
  EXPECT_EQ(g_exact.x(), s.gradient.x()) << x << "," << y;
  EXPECT_EQ(g_exact.y(), s.gradient.y()) << x << "," << y;
  const HeightSample px = f.sample(x + e, y), mx = f.sample(x - e, y);
  const HeightSample py = f.sample(x, y + e), my = f.sample(x, y - e);
  const Eigen::Vector2d hx = (px.gradient - mx.gradient) / (2 * e);
  const Eigen::Vector2d hy = (py.gradient - my.gradient) / (2 * e);
  const double tol = 1e-4 * (1 + s.hessian.norm());
  EXPECT_NEAR(s.hessian(0, 0), hx.x(), tol) << x << "," << y;
  EXPECT_NEAR(s.hessian(1, 0), hx.y(), tol) << x << "," << y;
  EXPECT_NEAR(s.hessian(0, 1), hy.x(), tol) << x << "," << y;
  EXPECT_NEAR(s.hessian(1, 1), hy.y(), tol) << x << "," << y;
}

}  // namespace

TEST(BSplineField, DerivativesMatchFiniteDifferencesEverywhere) {
  const GridGeometry g = geometry(13, 9);
  for (bool interp : {false, true}) {
    const BSplineField f(g, random_values(g, 7), interp);
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> ux(g.origin.x() - 0.05, g.max_corner().x() + 0.05);
    std::uniform_real_distribution<double> uy(g.origin.y() - 0.05, g.max_corner().y() + 0.05);
    for (int n = 0; n < 400; ++n) check_derivatives(f, ux(rng), uy(rng));
    // Right at and around knot lines (cell centres) and cell borders.
    for (int i = 0; i < g.nx; ++i)
      for (double off : {0.0, 1e-9, -1e-9, 0.5, 0.25}) {
        const double x = g.origin.x() + (i + 0.5 + off) * g.resolution;
        check_derivatives(f, x, g.origin.y() + 0.037);
        check_derivatives(f, g.origin.x() + 0.051,
                          g.origin.y() + (i % g.ny + 0.5 + off) * g.resolution);
      }
  }
}

TEST(BSplineField, IsC2AcrossKnotLines) {
  const GridGeometry g = geometry(10, 10);
  const BSplineField f(g, random_values(g, 11));
  for (int i = 0; i <= g.nx; ++i) {
    // Knots sit at cell centres (u integer); also the clamp at u = -1 and u = n outside the grid.
    for (double u : {i + 0.5, -0.5, g.nx + 0.5}) {
      const double x = g.origin.x() + u * g.resolution, y = g.origin.y() + 0.083;
      const double d = 1e-9;
      const HeightSample a = f.sample(x - d, y), b = f.sample(x + d, y);
      EXPECT_NEAR(a.height, b.height, 1e-8);
      EXPECT_NEAR((a.gradient - b.gradient).norm(), 0.0, 1e-5);  // ~2 d |H|
      EXPECT_NEAR((a.hessian - b.hessian).norm(), 0.0, 1e-3 * (1 + a.hessian.norm()));
    }
  }
}

TEST(BSplineField, ReproducesPlanesAndInterpolatesWhenAsked) {
  const GridGeometry g = geometry(12, 8);
  std::vector<float> plane(g.size());
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      const Eigen::Vector2d c = g.center(i, j);
      plane[g.index(i, j)] = static_cast<float>(0.3 * c.x() - 0.2 * c.y() + 0.05);
    }
  const BSplineField f(g, plane);
  // Away from the border (where padding replicates the edge values) a plane is reproduced exactly.
  const HeightSample s = f.sample(-0.17, 0.19);
  EXPECT_NEAR(s.height, 0.3 * -0.17 - 0.2 * 0.19 + 0.05, 1e-6);
  EXPECT_NEAR(s.gradient.x(), 0.3, 1e-5);
  EXPECT_NEAR(s.gradient.y(), -0.2, 1e-5);
  const auto values = random_values(g, 5);
  const BSplineField fi(g, values, true);
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      const Eigen::Vector2d c = g.center(i, j);
      EXPECT_NEAR(fi.value(c.x(), c.y()), values[g.index(i, j)], 1e-6);
    }
}

TEST(Safety, PalletSceneMaskMarginAndGradient) {
  auto scene = make_scene("pallet_10");
  const double r = 0.02;
  auto map = TerrainMap::from_scene(*scene, 0.02, {r, 0.05, 0.10});
  const auto& g = map->grid().geometry;
  const auto& layer = map->layer(r);
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      const Eigen::Vector2d c = g.center(i, j);
      const double d = scene->edge_distance(c.x(), c.y());
      const bool border = i < 2 || j < 2 || i >= g.nx - 2 || j >= g.ny - 2;
      const bool safe = layer.safe[g.index(i, j)];
      if (d <= r) {
        EXPECT_FALSE(safe) << c.transpose();
      }
      if (d >= r + 2 * g.resolution && !border) {
        EXPECT_TRUE(safe) << c.transpose();
      }
      // The margin agrees in sign with the mask at every cell centre.
      EXPECT_EQ(map->safety_margin(c.x(), c.y(), r).margin > 0, safe) << c.transpose();
    }
  // Larger feet: more unsafe cells.
  EXPECT_GT(layer.safe_cells, map->layer(0.05).safe_cells);
  EXPECT_GT(map->layer(0.05).safe_cells, map->layer(0.10).safe_cells);
  // On the pallet top, 10 cm from the front edge, the margin is about 10 cm - r.
  EXPECT_NEAR(map->safety_margin(0.65, 0.0, r).margin, 0.10 - r, 0.025);
  // The gradient is usable (points away from the edge) and matches finite differences.
  const double e = 1e-6;
  for (double x : {0.35, 0.47, 0.6, 0.71, 1.0}) {
    for (double y : {-0.3, 0.0, 0.21}) {
      const auto m = map->safety_margin(x, y, r);
      const double gx =
          (map->safety_margin(x + e, y, r).margin - map->safety_margin(x - e, y, r).margin) /
          (2 * e);
      const double gy =
          (map->safety_margin(x, y + e, r).margin - map->safety_margin(x, y - e, r).margin) /
          (2 * e);
      EXPECT_NEAR(m.gradient.x(), gx, 1e-5) << x << "," << y;
      EXPECT_NEAR(m.gradient.y(), gy, 1e-5) << x << "," << y;
    }
  }
  EXPECT_LT(map->safety_margin(0.47, 0.0, r).gradient.x(), 0.0);  // before the edge: back off
  EXPECT_GT(map->safety_margin(0.65, 0.0, r).gradient.x(), 0.0);  // on top: move inwards
}

TEST(Safety, RasterisedScenesKeepHeights) {
  for (const auto& name : scene_names()) {
    auto scene = make_scene(name);
    auto map = TerrainMap::from_scene(*scene, 0.02, {0.02});
    const auto& g = map->grid().geometry;
    for (int i = 0; i < g.nx; i += 3)
      for (int j = 0; j < g.ny; j += 3) {
        const Eigen::Vector2d c = g.center(i, j);
        if (scene->edge_distance(c.x(), c.y()) < 0.05) continue;
        EXPECT_NEAR(map->height(c.x(), c.y()), scene->height(c.x(), c.y()), 1e-6) << name;
      }
  }
}

// height_and_gradient() (what the planner's rows read) is sample()'s height and gradient to the
// bit, on the rasterised maps (their own override) and on the exact scenes (the default).
TEST(HeightField, HeightAndGradientAreSamplesToTheBit) {
  std::mt19937 rng(7);
  for (const auto& name : scene_names()) {
    auto scene = make_scene(name);
    auto map = TerrainMap::from_scene(*scene, 0.02, {});
    const Eigen::Vector2d lo = map->min_corner(), hi = map->max_corner();
    std::uniform_real_distribution<double> ux(lo.x(), hi.x()), uy(lo.y(), hi.y());
    for (const HeightField* f : {static_cast<const HeightField*>(map.get()),
                                 static_cast<const HeightField*>(scene.get())})
      for (int n = 0; n < 200; ++n) {
        const double x = ux(rng), y = uy(rng);
        const HeightSample s = f->sample(x, y);
        Eigen::Vector2d g;
        EXPECT_EQ(f->height_and_gradient(x, y, &g), s.height) << name << " " << x << "," << y;
        EXPECT_EQ(g, s.gradient) << name << " " << x << "," << y;
        EXPECT_EQ(f->height(x, y), s.height) << name;
      }
  }
}

TEST(Safety, SlopeAndRoughnessLimits) {
  const GridGeometry g = geometry(40, 40);
  HeightGrid grid;
  grid.geometry = g;
  const size_t n = g.size();
  grid.variance.assign(n, 0);
  grid.count.assign(n, 5);
  grid.support.assign(n, 5);
  grid.observed.assign(n, 1);
  auto ramp = [&](double slope) {
    grid.elevation.resize(n);
    for (int i = 0; i < g.nx; ++i)
      for (int j = 0; j < g.ny; ++j)
        grid.elevation[g.index(i, j)] = float(slope * g.center(i, j).x());
    grid.min = grid.max = grid.elevation;
  };
  SafetyOptions o;
  o.max_step = 1.0;  // only the slope matters here
  ramp(0.5);
  EXPECT_GT(compute_safety(grid, 0.05, o).safe_cells, 0u);
  ramp(0.7);
  EXPECT_EQ(compute_safety(grid, 0.05, o).safe_cells, 0u);
  // Rough: alternating +-2 cm checkerboard fails the plane-fit RMS.
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) grid.elevation[g.index(i, j)] = (i + j) % 2 ? 0.02f : -0.02f;
  grid.min = grid.max = grid.elevation;
  EXPECT_EQ(compute_safety(grid, 0.05, o).safe_cells, 0u);
  // A hole: cells whose disk reaches an unobserved cell are unsafe.
  for (auto& z : grid.elevation) z = 0;
  grid.min = grid.max = grid.elevation;
  grid.observed[g.index(20, 20)] = 0;
  const auto l = compute_safety(grid, 0.02, o);
  EXPECT_FALSE(l.safe[g.index(21, 21)]);
  EXPECT_FALSE(l.safe[g.index(20, 20)]);
  EXPECT_TRUE(l.safe[g.index(23, 20)]);
  EXPECT_THROW(compute_safety(grid, -0.1, o), terrastride::perception::InputError);
}

TEST(Clearance, SegmentAboveStep) {
  auto scene = make_scene("pallet_15");
  auto map = TerrainMap::from_scene(*scene, 0.02, {0.02});
  // A shin segment passing 5 cm over the pallet top: min clearance ~5 cm, found on top.
  const auto c = map->clearance({1.0, 0.0, 0.20}, {1.3, 0.0, 0.20});
  EXPECT_NEAR(c.min, 0.05, 1e-3);
  // A segment dipping through the pallet front edge: negative clearance.
  const auto d = map->clearance({0.40, 0.0, 0.05}, {0.70, 0.0, 0.10});
  EXPECT_LT(d.min, 0.0);
  EXPECT_GT(d.at.x(), 0.55);
}

TEST(TerrainDir, WriteThenLoadRoundTrip) {
  namespace fs = std::filesystem;
  auto scene = make_scene("stairs");
  auto map = TerrainMap::from_scene(*scene, 0.02, {0.02, 0.05});
  const fs::path dir =
      fs::temp_directory_path() / ("terrastride_terrain_dir_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  nlohmann::json meta = write_terrain_layers(*map, dir.string());
  { std::ofstream(dir / "terrain.json") << meta.dump(2); }
  auto loaded = load_terrain_dir(dir.string());
  EXPECT_EQ(loaded->radii().size(), 2u);
  for (double x : {0.1, 0.6, 0.93, 1.4})
    for (double y : {-0.2, 0.3}) {
      EXPECT_NEAR(loaded->height(x, y), map->height(x, y), 1e-6);
      EXPECT_NEAR(loaded->safety_margin(x, y, 0.02).margin, map->safety_margin(x, y, 0.02).margin,
                  1e-5);
      EXPECT_EQ(loaded->safe(x, y, 0.05), map->safe(x, y, 0.05));
    }
  // Mislabeled: a layer of the wrong shape, and a terrain.json that is not one.
  std::ofstream(dir / "terrain.json") << "{\"format\": \"something-else\"}";
  EXPECT_THROW(load_terrain_dir(dir.string()), terrastride::perception::InputError);
  EXPECT_THROW(load_terrain_dir((dir / "missing").string()), terrastride::perception::InputError);
  fs::remove_all(dir);
}

namespace {
// A flat grid at z = 0 with a 0.6 m shelf over cells i in [15, 25), j in [10, 30).
HeightGrid grid_with_shelf() {
  const GridGeometry g = geometry(40, 40);
  HeightGrid grid;
  grid.geometry = g;
  const size_t n = g.size();
  grid.elevation.assign(n, 0.0f);
  grid.min = grid.max = grid.elevation;
  grid.variance.assign(n, 0);
  grid.count.assign(n, 5);
  grid.support.assign(n, 5);
  grid.observed.assign(n, 1);
  grid.overhead.assign(n, std::numeric_limits<float>::infinity());
  for (int i = 15; i < 25; ++i)
    for (int j = 10; j < 30; ++j) grid.overhead[g.index(i, j)] = 0.6f;
  return grid;
}
}  // namespace

TEST(Overhead, FieldNeverRisesIntoTheOverhangAndIsInfiniteFarFromIt) {
  const HeightGrid grid = grid_with_shelf();
  const GridGeometry g = grid.geometry;
  TerrainMap map(grid, {0.02});
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> ux(g.origin.x(), g.max_corner().x()),
      uy(g.origin.y(), g.max_corner().y());
  int under = 0, finite_outside = 0;
  for (int s = 0; s < 5000; ++s) {
    const double x = ux(rng), y = uy(rng);
    const double o = map.overhead(x, y);
    const int k = map.cell_index(x, y);
    ASSERT_GE(k, 0);
    // Conservative: never above the raw overhead of the cell the point lies in.
    EXPECT_LE(o, grid.overhead[k] + 1e-6) << x << " " << y;
    if (std::isfinite(grid.overhead[k])) {
      ++under;
      EXPECT_LE(o, 0.6 + 1e-6);
    } else if (std::isfinite(o)) {
      ++finite_outside;
      EXPECT_GE(o, 0.6 - 1e-6);  // between the shelf's value and the cap
      EXPECT_LE(o, kOverheadCap + 1e-6);
    }
  }
  EXPECT_GT(under, 500);
  EXPECT_GT(finite_outside, 0);
  // Deep under the shelf the field is the shelf; far from it there is nothing overhead.
  EXPECT_NEAR(map.overhead(g.center(20, 20).x(), g.center(20, 20).y()), 0.6, 1e-6);
  EXPECT_TRUE(std::isinf(map.overhead(g.center(2, 2).x(), g.center(2, 2).y())));
  // A map without the layer has nothing overhead anywhere.
  HeightGrid plain = grid;
  plain.overhead.clear();
  EXPECT_TRUE(std::isinf(TerrainMap(plain, {0.02}).overhead(g.center(20, 20).x(), 0.5)));
}

TEST(Overhead, GradientMatchesFiniteDifferences) {
  TerrainMap map(grid_with_shelf(), {0.02});
  const GridGeometry& g = map.grid().geometry;
  const double h = 1e-6;
  for (int i = 11; i < 29; i += 3)
    for (int j = 6; j < 34; j += 5) {
      const double x = g.center(i, j).x() + 0.003, y = g.center(i, j).y() - 0.004;
      Eigen::Vector2d grad;
      const double o = map.overhead_and_gradient(x, y, &grad);
      if (!std::isfinite(o)) continue;
      const double dx = (map.overhead(x + h, y) - map.overhead(x - h, y)) / (2 * h);
      const double dy = (map.overhead(x, y + h) - map.overhead(x, y - h)) / (2 * h);
      EXPECT_NEAR(grad.x(), dx, 1e-4 * std::max(1.0, std::abs(dx)));
      EXPECT_NEAR(grad.y(), dy, 1e-4 * std::max(1.0, std::abs(dy)));
    }
}

TEST(Overhead, LayerSurvivesWriteAndLoadAndNaNIsRefused) {
  namespace fs = std::filesystem;
  HeightGrid grid = grid_with_shelf();
  TerrainMap map(grid, {0.02});
  const fs::path dir =
      fs::temp_directory_path() / ("terrastride_overhead_dir_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  nlohmann::json meta = write_terrain_layers(map, dir.string());
  EXPECT_TRUE(meta.at("layers").contains("overhead"));
  { std::ofstream(dir / "terrain.json") << meta.dump(2); }
  auto loaded = load_terrain_dir(dir.string());
  ASSERT_EQ(loaded->grid().overhead.size(), grid.overhead.size());
  for (size_t k = 0; k < grid.overhead.size(); ++k)
    EXPECT_EQ(loaded->grid().overhead[k], grid.overhead[k]);
  const GridGeometry& g = grid.geometry;
  EXPECT_NEAR(loaded->overhead(g.center(20, 20).x(), g.center(20, 20).y()), 0.6, 1e-6);
  fs::remove_all(dir);
  grid.overhead[3] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(TerrainMap(grid, {0.02}), terrastride::perception::InputError);
}

// A map folder is user input (`query`, `report`, `plan --terrain`): terrain.json's numbers and
// the layers' values are checked before any conversion. get<int>() of an nx written as 1e300, a
// cast of a count of 1e20 or -1 to uint32_t, of 1e300 to float, or floor(max_climb / res) of a
// max_climb of 1e300 to int were undefined behaviour (UBSan: "outside the range of representable
// values").
TEST(TerrainDir, HostileMetadataAndLayersAreRefusedByName) {
  namespace fs = std::filesystem;
  using terrastride::perception::InputError;
  const TerrainMap map(grid_with_shelf(), {0.02});
  const fs::path dir =
      fs::temp_directory_path() / ("terrastride_hostile_dir_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const nlohmann::json meta = write_terrain_layers(map, dir.string());
  const auto error_with = [&](const nlohmann::json& m) -> std::string {
    std::ofstream(dir / "terrain.json") << m.dump();
    try {
      (void)load_terrain_dir(dir.string());
    } catch (const InputError& e) {
      return e.what();
    }
    return "";
  };
  ASSERT_EQ(error_with(meta), "");
  const struct {
    const char* pointer;
    nlohmann::json value;
    const char* expected;
  } fields[] = {
      {"/grid/nx", 1e300, "grid: nx is 1e+300, not a whole number in [0, 10000000]"},
      {"/grid/nx", 2.5, "grid: nx is 2.5, not a whole number"},
      {"/grid/ny", -40, "grid: ny is -40, not a whole number"},
      {"/grid/resolution", 1e-300, "grid: resolution 1e-300 m is outside"},
      {"/grid/noise/bins", 1e300, "grid.noise: bins is 1e+300, not a whole number"},
  };
  for (const auto& f : fields) {
    nlohmann::json m = meta;
    m[nlohmann::json::json_pointer(f.pointer)] = f.value;
    EXPECT_NE(error_with(m).find(f.expected), std::string::npos)
        << f.pointer << ": " << error_with(m);
  }
  // A reach beyond the grid is the whole grid: the map loads.
  nlohmann::json far = meta;
  far["safety"]["max_climb"] = 1e300;
  EXPECT_EQ(error_with(far), "");
  // Nesting beyond perception::kMaxJsonNesting is malformed JSON.
  nlohmann::json deep = meta;
  deep["notes_extra"] = nlohmann::json::array();
  nlohmann::json* inner = &deep["notes_extra"];
  for (int k = 0; k < 200; ++k) inner = &inner->emplace_back(nlohmann::json::array());
  EXPECT_NE(error_with(deep).find("nested more than 100 levels deep"), std::string::npos);

  // Layers: a value the grid's element type cannot hold.
  const GridGeometry& g = map.grid().geometry;
  const auto layer_error = [&](const char* name, double value) {
    std::vector<double> v(g.size(), 1.0);
    v[7] = value;
    const std::string path = (dir / "layers" / (std::string(name) + ".npy")).string();
    const std::string saved = path + ".saved";
    fs::copy_file(path, saved, fs::copy_options::overwrite_existing);
    terrastride::perception::write_npy(path, v.data(), g.nx, g.ny);
    const std::string e = error_with(meta);
    fs::rename(saved, path);
    return e;
  };
  EXPECT_NE(layer_error("count", 1e20).find("count.npy: a count layer holds a value"),
            std::string::npos);
  EXPECT_NE(layer_error("support", -1).find("support.npy: a count layer holds a value"),
            std::string::npos);
  EXPECT_NE(layer_error("count", 0.5).find("(cell 0, 7: 0.500000)"), std::string::npos);
  EXPECT_NE(layer_error("observed", 1e300).find("observed.npy: a count layer"),
            std::string::npos);
  EXPECT_NE(layer_error("elevation", 1e300).find("elevation.npy: value beyond a 32-bit float"),
            std::string::npos);
  EXPECT_NE(layer_error("elevation", std::nan("")).find("non-finite value in a layer"),
            std::string::npos);
  EXPECT_EQ(error_with(meta), "");
  fs::remove_all(dir);
}
