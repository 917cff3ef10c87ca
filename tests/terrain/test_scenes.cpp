#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/terrain/height_grid.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

using namespace terrastride::terrain;

TEST(Scenes, AllNamesBuildAndUnknownNameListsValidOnes) {
  for (const auto& n : scene_names()) {
    auto s = make_scene(n);
    ASSERT_TRUE(s);
    EXPECT_EQ(s->name(), n);
    EXPECT_NEAR(s->height(0.0, 0.0), 0.0, 1e-12) << n;  // the robot starts on the ground
  }
  try {
    make_scene("palet");
    FAIL() << "no error";
  } catch (const terrastride::perception::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("palet"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("pallet_15"), std::string::npos);
  }
}

TEST(Scenes, PalletHeightsAndEdges) {
  auto s = make_scene("pallet_15");
  EXPECT_DOUBLE_EQ(s->height(1.0, 0.0), 0.15);
  EXPECT_DOUBLE_EQ(s->height(0.5, 0.0), 0.0);
  EXPECT_DOUBLE_EQ(s->height(1.0, 0.7), 0.0);
  const auto hs = s->sample(1.0, 0.1);
  EXPECT_EQ(hs.gradient.norm(), 0.0);
  EXPECT_EQ(hs.hessian.norm(), 0.0);
  EXPECT_EQ(s->edges().size(), 4u);
  // Margin: distance to the nearest edge minus r, gradient pointing away from the edge.
  const auto m = s->safety_margin(0.60, 0.0, 0.02);
  EXPECT_NEAR(m.margin, 0.05 - 0.02, 1e-12);
  EXPECT_NEAR(m.gradient.x(), 1.0, 1e-12);
  const auto inside = s->safety_margin(0.56, 0.0, 0.02);
  EXPECT_LT(inside.margin, 0.0);
  // Finite-difference check of the margin gradient away from the medial axis.
  for (double x : {0.3, 0.6, 0.9, 1.6, 2.0}) {
    for (double y : {-0.8, -0.3, 0.1, 0.5}) {
      const double e = 1e-6;
      const auto c = s->safety_margin(x, y, 0.03);
      const double gx =
          (s->safety_margin(x + e, y, 0.03).margin - s->safety_margin(x - e, y, 0.03).margin) /
          (2 * e);
      const double gy =
          (s->safety_margin(x, y + e, 0.03).margin - s->safety_margin(x, y - e, 0.03).margin) /
          (2 * e);
      EXPECT_NEAR(c.gradient.x(), gx, 1e-6) << x << "," << y;
      EXPECT_NEAR(c.gradient.y(), gy, 1e-6) << x << "," << y;
    }
  }
}

TEST(Scenes, StairsGapAndEurPallet) {
  auto st = make_scene("stairs");
  EXPECT_DOUBLE_EQ(st->height(0.7, 0.0), 0.12);
  EXPECT_DOUBLE_EQ(st->height(1.0, 0.0), 0.24);
  EXPECT_DOUBLE_EQ(st->height(1.3, 0.0), 0.36);
  // The shared far end of the three stacked boxes is a single 0.36 m edge, not three.
  EXPECT_NEAR(st->edge_distance(1.70, 0.0), 0.05, 1e-12);
  auto gap = make_scene("gap");
  EXPECT_DOUBLE_EQ(gap->height(0.6, 0.0), -0.30);
  EXPECT_DOUBLE_EQ(gap->height(0.4, 0.0), 0.0);
  EXPECT_NEAR(gap->safety_margin(0.3, 0.0, 0.02).margin, 0.18, 1e-12);
  auto eur = make_scene("eur_pallet");
  EXPECT_DOUBLE_EQ(eur->height(1.0, 0.3), 0.144);     // outer deck board
  EXPECT_DOUBLE_EQ(eur->height(1.15, 0.235), 0.122);  // gap over the middle stringer board
  EXPECT_DOUBLE_EQ(eur->height(0.9, 0.235), 0.0);     // gap over nothing: the ground
  EXPECT_DOUBLE_EQ(eur->height(0.6, 0.235), 0.122);   // gap over the first stringer
}

TEST(Scenes, RayCast) {
  auto s = make_scene("pallet_10");
  // Straight down onto the pallet top.
  auto hit = s->ray_cast({1.0, 0.0, 0.8}, {0, 0, -1}, 5.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->range, 0.7, 1e-12);
  EXPECT_NEAR(hit->normal.z(), 1.0, 1e-12);
  // Horizontal ray at 5 cm hits the front face.
  hit = s->ray_cast({0.0, 0.0, 0.05}, {1, 0, 0}, 5.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->range, 0.55, 1e-12);
  EXPECT_NEAR(hit->normal.x(), -1.0, 1e-12);
  // Looking up: nothing. Out of range: nothing.
  EXPECT_FALSE(s->ray_cast({0, 0, 0.5}, {0, 0, 1}, 5.0));
  EXPECT_FALSE(s->ray_cast({0, 0, 0.8}, {0, 0, -1}, 0.5));
  // Under the EUR pallet deck (side view at 11 cm) the ray passes between blocks until a block.
  auto eur = make_scene("eur_pallet");
  hit = eur->ray_cast({0.0, 0.2, 0.06}, {1, 0, -0.02}, 5.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->point.x(), 3.0, 1e-9);  // y = 0.2 is between block rows: reaches the ground
  hit = eur->ray_cast({0.0, 0.0, 0.06}, {1, 0, -0.02}, 5.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->point.x(), 0.55, 1e-9);  // the middle block row
}

// pallet_NN: the pallet at any height from 1 to 60 cm (a step scaled to a robot's legs); HyQ's
// pallet_10 and pallet_15 keep their descriptions.
TEST(Scenes, PalletOfAnyHeight) {
  EXPECT_EQ(pallet_height_cm("pallet_14"), 14);
  EXPECT_DOUBLE_EQ(make_scene("pallet_14")->height(1.0, 0.0), 0.14);
  EXPECT_DOUBLE_EQ(make_scene("pallet_21")->height(1.0, 0.0), 0.21);
  EXPECT_NE(make_scene("pallet_21")->describe().find("solid box 0.21 m high"), std::string::npos);
  EXPECT_NE(make_scene("pallet_10")->describe().find("solid box 0.10 m high, x in [0.55, 1.75]"),
            std::string::npos);
  EXPECT_TRUE(is_scene_name("pallet_60"));
  EXPECT_TRUE(is_scene_name("stairs"));
  // The list every help text and error prints: the named scenes and pallet_NN.
  const std::string text = scene_names_text();
  for (const auto& n : scene_names()) {
    EXPECT_TRUE(is_scene_name(n)) << n;
    EXPECT_NE(text.find(n), std::string::npos) << text;
  }
  EXPECT_NE(text.find("pallet_NN"), std::string::npos) << text;
  try {
    make_scene("pallet_61");
  } catch (const terrastride::perception::InputError& e) {
    EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
  }
  for (const char* bad : {"pallet_0", "pallet_07", "pallet_61", "pallet_1x", "pallet_", "pallet_123"}) {
    EXPECT_FALSE(is_scene_name(bad)) << bad;
    EXPECT_THROW(make_scene(bad), terrastride::perception::InputError) << bad;
  }
}

// shelf_60: a slab whose underside is 0.6 m up over x in [0.4, 0.9], |y| <= 0.8, on four legs at
// |y| >= 0.72. The walkable surface is the ground beneath it (and the legs' tops), the overhead
// its underside, and ray casts meet it as a solid.
TEST(Scenes, ShelfSeparatesTheWalkableSurfaceFromTheOverhang) {
  const auto s = make_scene("shelf_60");
  const double inf = std::numeric_limits<double>::infinity();
  // Under the shelf: ground to walk on, the underside overhead.
  EXPECT_DOUBLE_EQ(s->height(0.65, 0.0), 0.0);
  EXPECT_DOUBLE_EQ(s->overhead(0.65, 0.0), 0.60);
  EXPECT_DOUBLE_EQ(s->overhead(0.40, 0.0), 0.60);  // closed footprint: its border is covered
  Eigen::Vector2d g(1, 1);
  EXPECT_DOUBLE_EQ(s->overhead_and_gradient(0.6, 0.3, &g), 0.60);
  EXPECT_EQ(g.norm(), 0.0);
  // Beside it: ground, nothing overhead.
  EXPECT_DOUBLE_EQ(s->height(0.2, 0.0), 0.0);
  EXPECT_EQ(s->overhead(0.2, 0.0), inf);
  EXPECT_EQ(s->overhead(0.39, 0.0), inf);
  EXPECT_EQ(s->overhead(0.65, 0.85), inf);
  EXPECT_EQ(s->overhead(1.0, 0.0), inf);
  // On a leg: its top (under the slab) is the walkable surface; the slab is still overhead.
  EXPECT_DOUBLE_EQ(s->height(0.44, 0.76), 0.60);
  EXPECT_DOUBLE_EQ(s->height(0.44, -0.76), 0.60);
  // The path is free of edges: the nearest ones are the legs', 0.72 m to the side.
  EXPECT_NEAR(s->edge_distance(0.44, 0.0), 0.72, 1e-12);
  EXPECT_NEAR(s->safety_margin(0.44, 0.0, 0.02).margin, 0.70, 1e-12);
  EXPECT_EQ(s->edges().size(), 16u);  // four legs, four sides each: the slab adds none
  // Rays: from above onto the slab's top; upwards from under it onto its underside; level under
  // it, along the path, through to nothing in range; level at a leg's height into a leg.
  auto hit = s->ray_cast({0.65, 0.0, 1.5}, {0, 0, -1}, 5.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->point.z(), 0.64, 1e-12);
  EXPECT_NEAR(hit->normal.z(), 1.0, 1e-12);
  hit = s->ray_cast({0.65, 0.0, 0.2}, {0, 0, 1}, 5.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->point.z(), 0.60, 1e-12);
  EXPECT_NEAR(hit->normal.z(), -1.0, 1e-12);
  EXPECT_FALSE(s->ray_cast({-0.5, 0.0, 0.3}, {1, 0, 0}, 2.0));
  hit = s->ray_cast({0.44, 0.0, 0.3}, {0, 1, 0}, 2.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->point.y(), 0.72, 1e-12);
  // A sensor at 0.8 m looking down the path sees the slab's top in front of the ground behind it.
  hit = s->ray_cast({0.0, 0.0, 0.8}, {1, 0, -0.3}, 5.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->point.z(), 0.64, 1e-12);
}

// The other overhang scenes and the names: half_shelf covers the path's left half only, tread
// stands over the start; the heights run from 25 to 150 cm; scenes without an overhang have
// nothing overhead anywhere (eur_pallet's boards, 10-12 cm up, stay ground).
TEST(Scenes, OverhangScenesAndNames) {
  const double inf = std::numeric_limits<double>::infinity();
  const auto half = make_scene("half_shelf_45");
  EXPECT_DOUBLE_EQ(half->overhead(0.65, 0.1), 0.45);
  EXPECT_EQ(half->overhead(0.65, -0.1), inf);
  EXPECT_DOUBLE_EQ(half->height(0.65, 0.1), 0.0);
  const auto tread = make_scene("tread_50");
  EXPECT_DOUBLE_EQ(tread->overhead(0.0, 0.0), 0.50);  // above the start
  EXPECT_EQ(tread->overhead(0.5, 0.0), inf);
  EXPECT_DOUBLE_EQ(tread->height(0.0, 0.0), 0.0);
  EXPECT_DOUBLE_EQ(make_scene("shelf_25")->overhead(0.6, 0), 0.25);
  EXPECT_DOUBLE_EQ(make_scene("shelf_150")->overhead(0.6, 0), 1.50);
  for (const char* bad : {"shelf_24", "shelf_151", "shelf_060", "shelf_", "tread_x", "half_shelf"})
    EXPECT_THROW(make_scene(bad), terrastride::perception::InputError) << bad;
  for (const auto& n : scene_names()) {
    const auto s = make_scene(n);
    for (double x = -0.5; x <= 2.0; x += 0.05)
      for (double y = -0.5; y <= 0.5; y += 0.05) ASSERT_EQ(s->overhead(x, y), inf) << n;
  }
  // eur_pallet's top surface is its deck boards, as before.
  EXPECT_DOUBLE_EQ(make_scene("eur_pallet")->height(1.0, 0.0), 0.144);
  EXPECT_NE(scene_names_text().find("shelf_NN"), std::string::npos);
}

// rasterize_scene carries the overhang into the grid (the planner sees scenes through
// TerrainMap::from_scene): each cell's overhead is the lowest underside over any part of it, so a
// cell the shelf's border crosses is covered; scenes without an overhang have no layer.
TEST(Scenes, RasterisedShelfCarriesItsOverhead) {
  const auto s = make_scene("shelf_60");
  const HeightGrid grid = rasterize_scene(*s, 0.02);
  const GridGeometry& g = grid.geometry;
  ASSERT_EQ(grid.overhead.size(), g.size());
  auto cell = [&](double x, double y) {
    return g.index(static_cast<int>(std::floor((x - g.origin.x()) / g.resolution)),
                   static_cast<int>(std::floor((y - g.origin.y()) / g.resolution)));
  };
  EXPECT_FLOAT_EQ(grid.overhead[cell(0.65, 0.01)], 0.6f);
  EXPECT_FLOAT_EQ(grid.elevation[cell(0.65, 0.01)], 0.0f);
  EXPECT_FLOAT_EQ(grid.overhead[cell(0.391, 0.01)], 0.6f);  // the cell [0.38, 0.40] touches it
  EXPECT_TRUE(std::isinf(grid.overhead[cell(0.37, 0.01)]));
  EXPECT_TRUE(std::isinf(grid.overhead[cell(0.65, 0.85)]));
  const auto map = TerrainMap::from_scene(*s, 0.02, {});
  EXPECT_NEAR(map->overhead(0.65, 0.0), 0.6, 1e-6);
  EXPECT_TRUE(std::isinf(map->overhead(0.0, 0.0)));
  for (double x = 0.4; x <= 0.9; x += 0.01) EXPECT_LE(map->overhead(x, 0.0), 0.6 + 1e-6) << x;
  EXPECT_TRUE(rasterize_scene(*make_scene("pallet_15"), 0.02).overhead.empty());
}
