// The registry of constraint sets (constraints/registry.cpp): the names `--constraints` accepts,
// "all" and the implied sets expanded, each set once, unknown names refused by name.
#include <algorithm>

#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

TEST(Registry, AllExpandsAndNamesAreListed) {
  const auto names = constraint_set_names();
  for (const std::string n :
       {"baseline", "foot", "shin", "shin_ik", "thigh", "trunk", "polytope", "swing",
        "joints", "force_ramp", "monotone_progress", "lateral_corridor", "swing_apex", "all"})
    EXPECT_NE(std::find(names.begin(), names.end(), n), names.end()) << n;
  const auto r = hyq();
  FlatField flat;
  const PhaseTimeline tl = make_timeline(load_gait(resolve_gait_path("crawl")), feet_of(r), 1, 2.0);
  PlannerOptions a, b;
  a.constraints = {"all"};
  b.constraints = {"baseline",         "foot",       "shin_ik",          "thigh",
                   "trunk",            "polytope",   "joints",           "force_ramp",
                   "monotone_progress", "lateral_corridor", "swing_apex", "foot"};  // once each
  SrbdProblem pa(r, flat, tl, a), pb(r, flat, tl, b);
  EXPECT_EQ(count_kinds(pa), count_kinds(pb));
  EXPECT_EQ(pa.num_constraints(), pb.num_constraints());
  PlannerOptions c;
  c.constraints = {"all", "shinn"};
  try {
    SrbdProblem pc(r, flat, tl, c);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("shinn"), std::string::npos) << e.what();
  }
}

TEST(Registry, PolytopeImpliesSwing) {
  const auto r = hyq();
  FlatField flat;
  PlannerOptions poly, both, base, all;
  poly.constraints = {"polytope"};
  both.constraints = {"polytope", "swing"};
  base.constraints = {"baseline"};
  all.constraints = {"all"};
  const SrbdProblem pp(r, flat, crawl_timeline(r), poly), pb(r, flat, crawl_timeline(r), both),
      p0(r, flat, crawl_timeline(r), base), pa(r, flat, crawl_timeline(r), all);
  EXPECT_GT(count_kinds(pp)["swing"], 0);
  EXPECT_EQ(count_kinds(pp), count_kinds(pb));  // added once
  EXPECT_EQ(count_kinds(p0).count("swing"), 0u);
  EXPECT_EQ(count_kinds(pa)["swing"], count_kinds(pp)["swing"]);
  const auto names = constraint_set_names();
  EXPECT_NE(std::find(names.begin(), names.end(), "swing"), names.end());
}

}  // namespace
}  // namespace terrastride::planner
