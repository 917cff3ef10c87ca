// A re-plan from a measured state outside a joint's range and a foot's range-of-motion box
// (SrbdProblem::add_piece, constraints/start_return.hpp): the rows on the pinned start
// alone are left out and reported, the joints and range_of_motion rows after it get the start's
// excess as room, shrinking to nothing over start_return, and their Jacobians still match central
// differences. A start within the bounds (and every cold plan) keeps its rows as they were. A
// session step's pinned end outside them likewise: its rows are left out and reported as the
// end's, and the rows before it get its excess as room, growing over start_return up to the end.
#include <algorithm>
#include <cmath>
#include <set>

#include "../../../planner/src/constraints/start_return.hpp"
#include "family_test.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

struct Replan {
  SrbdProblem::StartState start;
  PhaseTimeline timeline;
};

// The cold crawl's state at 0.5 s, its base rolled by `roll` rad and moved `dy` m sideways (the
// feet stay where they stand): after a push.
Replan pushed_start(const robot::RobotModel& r, const terrain::HeightField& terrain, const ProblemOptions& o,
                    double roll, double dy) {
  const SrbdProblem cold(r, terrain, crawl_timeline(r), o);
  Replan p{start_state_of(cold.evaluate(const_cast<SrbdProblem&>(cold).initial_guess(), 0.5)),
           crawl_timeline(r).cropped(0.5)};
  p.start.euler_zyx[2] += roll;
  p.start.position.y() += dy;
  return p;
}

ProblemOptions joints_and_box_options() {
  ProblemOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.4, 0.0, 0.0);
  o.constraints = {"baseline", "joints"};
  return o;
}

// Whether piece `p`'s variables are all fixed in `problem`.
bool constant(const SrbdProblem& problem, const Piece& p) {
  for (int v : p.vars)
    if (problem.lower()[v] < problem.upper()[v]) return false;
  return true;
}

// The first (or last) base knot whose variables piece `a` reads: its time, up to a segment.
int base_knot_read(const Layout& L, const Piece& a, bool last) {
  for (int i = 0; i <= L.num_segments; ++i) {
    const int k = last ? L.num_segments - i : i;
    if (std::find(a.vars.begin(), a.vars.end(), L.base[k]) != a.vars.end()) return k;
  }
  return -1;
}

// The joints and range_of_motion pieces of `p` (a problem with room) against those of `q` (the
// same problem without): every other piece keeps its bounds, these are never narrower. Per such
// piece its kind, the base knot it reads (first or last) and whether a bound moved; and the
// largest room of any row.
struct RoomPiece {
  std::string kind;
  int knot = -1;
  bool differs = false;
};
void compare_room(const SrbdProblem& p, const SrbdProblem& q, bool last_knot,
                  std::vector<RoomPiece>* pieces, double* largest_room) {
  ASSERT_EQ(p.pieces().size(), q.pieces().size());
  *largest_room = 0.0;
  for (std::size_t i = 0; i < p.pieces().size(); ++i) {
    const Piece &a = *p.pieces()[i], &b = *q.pieces()[i];
    ASSERT_EQ(a.kind, b.kind);
    ASSERT_EQ(a.vars, b.vars);
    if (a.kind != "joints" && a.kind != "range_of_motion") {
      EXPECT_EQ(a.lb, b.lb) << a.kind;
      EXPECT_EQ(a.ub, b.ub) << a.kind;
      continue;
    }
    RoomPiece r{a.kind, base_knot_read(p.layout(), a, last_knot), false};
    ASSERT_GE(r.knot, 0);
    for (int row = 0; row < a.rows(); ++row) {
      EXPECT_LE(a.lb[row], b.lb[row]);
      EXPECT_GE(a.ub[row], b.ub[row]);
      r.differs |= a.lb[row] != b.lb[row] || a.ub[row] != b.ub[row];
      *largest_room = std::max({*largest_room, b.lb[row] - a.lb[row], a.ub[row] - b.ub[row]});
    }
    pieces->push_back(r);
  }
}

TEST(StartReturn, AMeasuredStartsOwnViolationsAreReportedNotImposed) {
  const auto r = hyq();
  FlatField flat;
  const ProblemOptions o = joints_and_box_options();
  const Replan pushed = pushed_start(r, flat, o, -0.30, -0.05);
  const SrbdProblem p(r, flat, pushed.timeline, o, &pushed.start);
  const auto& excess = p.start_excess();
  ASSERT_TRUE(excess.count("joints")) << "the pushed start should lie outside a joint's range";
  ASSERT_TRUE(excess.count("range_of_motion")) << "and outside a foot's box";
  std::printf("start excess: joints %.3f rad, range_of_motion %.3f m\n", excess.at("joints"),
              excess.at("range_of_motion"));
  EXPECT_GT(excess.at("joints"), 0.01);
  EXPECT_GT(excess.at("range_of_motion"), 0.01);
  // No row left that is a constant outside its bounds.
  const auto& x = const_cast<SrbdProblem&>(p).initial_guess();
  for (const auto& piece : p.pieces()) {
    if (!constant(p, *piece)) continue;
    const auto g = rows_at(*piece, x);
    for (int row = 0; row < piece->rows(); ++row) {
      EXPECT_GE(g[row], piece->lb[row]) << piece->kind;
      EXPECT_LE(g[row], piece->ub[row]) << piece->kind;
    }
  }
  // The same start unpushed: within every bound, nothing left out, the same rows as before.
  const Replan on_plan = pushed_start(r, flat, o, 0.0, 0.0);
  const SrbdProblem q(r, flat, on_plan.timeline, o, &on_plan.start);
  EXPECT_TRUE(q.start_excess().empty());
}

// A session step pins its horizon end to the reference too: a row that only the pinned end makes
// constant, and that the end violates (here an end rolled and moved aside as a push would), is left
// out like the start's but reported as the end's, not the measured start's, which lies within
// every bound here.
TEST(StartReturn, APinnedEndsViolationIsNotReportedAsTheStarts) {
  const auto r = hyq();
  FlatField flat;
  const ProblemOptions o = joints_and_box_options();
  const Replan on_plan = pushed_start(r, flat, o, 0.0, 0.0);
  const SrbdProblem cold(r, flat, crawl_timeline(r), o);
  for (const double t_end : {0.9, 1.5, 2.0}) {
    SrbdProblem::StartState end =
        start_state_of(cold.evaluate(const_cast<SrbdProblem&>(cold).initial_guess(), t_end));
    const PhaseTimeline horizon = crawl_timeline(r, t_end).cropped(0.5);
    const SrbdProblem unmoved(r, flat, horizon, o, &on_plan.start, &end);
    EXPECT_TRUE(unmoved.start_excess().empty()) << t_end;
    end.euler_zyx[2] -= 0.30;
    end.position.y() -= 0.05;
    const SrbdProblem p(r, flat, horizon, o, &on_plan.start, &end);
    EXPECT_TRUE(p.start_excess().empty()) << "the start lies on the plan; end at " << t_end;
    ASSERT_FALSE(p.end_excess().empty()) << "the moved end should leave a joint range or a box";
    for (const auto& [kind, excess] : p.end_excess())
      EXPECT_GT(excess, SrbdProblem::kConstantExcessReportMin) << kind;
  }
  // A pushed start with the same moved end: the start's excess is the start's.
  const Replan pushed = pushed_start(r, flat, o, -0.30, -0.05);
  SrbdProblem::StartState end =
      start_state_of(cold.evaluate(const_cast<SrbdProblem&>(cold).initial_guess(), 2.0));
  const SrbdProblem both(r, flat, crawl_timeline(r, 2.0).cropped(0.5), o, &pushed.start, &end);
  EXPECT_TRUE(both.start_excess().count("joints"));
}

// The end moved as a push would have moved the robot by then (rolled 0.5 rad, 5 cm aside): a
// session step's pinned end outside a joint range and a box, from a start on the plan.
struct MovedEnd {
  Replan start;
  SrbdProblem::StartState end;
  PhaseTimeline horizon;
};
MovedEnd moved_end(const robot::RobotModel& r, const terrain::HeightField& terrain,
                   const ProblemOptions& o, double roll = -0.5, double dy = -0.05) {
  const SrbdProblem cold(r, terrain, crawl_timeline(r), o);
  MovedEnd m{pushed_start(r, terrain, o, 0.0, 0.0),
             start_state_of(cold.evaluate(const_cast<SrbdProblem&>(cold).initial_guess(), 2.0)),
             crawl_timeline(r, 2.0).cropped(0.5)};
  m.end.euler_zyx[2] += roll;
  m.end.position.y() += dy;
  return m;
}

// The rows before a pinned end outside its bounds: widened by the end's excess towards the end,
// as they were up to start_return before it (the step ends at 1.5 s: up to 0.5 s), never by more
// than the excess, and only the joints and range_of_motion rows. Before this every row kept its
// bound, and a step whose stance foothold (fixed by the measured start) lay outside its box at
// the pinned end was infeasible by construction (test_plan.cpp,
// Plan.SessionStepWithASlippedFootholdUpToItsPinnedEndSolves).
TEST(StartReturn, RowsBeforeAPinnedEndGetItsExcessBackToTheBound) {
  const auto r = hyq();
  FlatField flat;
  const ProblemOptions o = joints_and_box_options();
  const MovedEnd m = moved_end(r, flat, o);
  const SrbdProblem p(r, flat, m.horizon, o, &m.start.start, &m.end);
  ProblemOptions none = o;
  none.feasibility_settings = {{"start_return", 0.0}};
  const SrbdProblem q(r, flat, m.horizon, none, &m.start.start, &m.end);
  ASSERT_TRUE(p.start_excess().empty());
  ASSERT_TRUE(p.end_excess().count("joints"));
  ASSERT_TRUE(p.end_excess().count("range_of_motion"));
  const double span = FeasibilityOptions{}.start_return;
  const auto& L = p.layout();
  const double t_end = L.nominal_knot_time[L.num_segments];
  EXPECT_NEAR(t_end, 1.5, 1e-9);
  std::vector<RoomPiece> room;
  double largest_room = 0.0;
  compare_room(p, q, /*last_knot=*/true, &room, &largest_room);
  if (HasFatalFailure()) return;
  int widened = 0, same_before_span = 0;
  for (const RoomPiece& piece : room) {
    widened += piece.differs;
    if (L.nominal_knot_time[piece.knot] <= t_end - span + 1e-9) {
      EXPECT_FALSE(piece.differs) << piece.kind << " up to knot " << piece.knot << " (t "
                                  << L.nominal_knot_time[piece.knot] << " s)";
      ++same_before_span;
    }
  }
  EXPECT_GT(widened, 0);
  EXPECT_GT(same_before_span, 0);
  double most = 0.0;
  for (const auto& [kind, excess] : p.end_excess()) most = std::max(most, excess);
  EXPECT_LE(largest_room, most + 1e-12);
  EXPECT_GT(largest_room, 0.0);
  // The end not moved: within its bounds, every row as without room.
  const MovedEnd on = moved_end(r, flat, o, 0.0, 0.0);
  const SrbdProblem u(r, flat, on.horizon, o, &on.start.start, &on.end);
  const SrbdProblem v(r, flat, on.horizon, none, &on.start.start, &on.end);
  EXPECT_TRUE(u.end_excess().empty());
  ASSERT_EQ(u.pieces().size(), v.pieces().size());
  for (std::size_t i = 0; i < u.pieces().size(); ++i) {
    EXPECT_EQ(u.pieces()[i]->lb, v.pieces()[i]->lb) << u.pieces()[i]->kind;
    EXPECT_EQ(u.pieces()[i]->ub, v.pieces()[i]->ub) << u.pieces()[i]->kind;
  }
}

// The rows after the start: widened by the excess at first, back to the bound from start_return
// on; the joints rows' bounds never narrower than the joint range less the margin.
TEST(StartReturn, RowsAfterTheStartGetTheExcessBackToTheBound) {
  const auto r = hyq();
  FlatField flat;
  const ProblemOptions o = joints_and_box_options();
  const Replan pushed = pushed_start(r, flat, o, -0.30, -0.05);
  const SrbdProblem p(r, flat, pushed.timeline, o, &pushed.start);
  ProblemOptions none = o;
  none.feasibility_settings = {{"start_return", 0.0}};
  const SrbdProblem q(r, flat, pushed.timeline, none, &pushed.start);
  const double span = FeasibilityOptions{}.start_return;
  const auto& L = p.layout();
  std::vector<RoomPiece> room;
  double largest_room = 0.0;
  compare_room(p, q, /*last_knot=*/false, &room, &largest_room);
  if (HasFatalFailure()) return;
  int widened = 0, same_after_span = 0;
  for (const RoomPiece& piece : room) {
    widened += piece.differs;
    // Pieces whose first knot is at or beyond the span (a segment's points lie after its knot).
    if (L.nominal_knot_time[piece.knot] >= span) {
      EXPECT_FALSE(piece.differs) << piece.kind << " at knot " << piece.knot << " (t "
                                  << L.nominal_knot_time[piece.knot] << " s)";
      ++same_after_span;
    }
  }
  EXPECT_GT(widened, 0);
  EXPECT_GT(same_after_span, 0);
  // The room never exceeds the start's excess.
  const double most = std::max(p.start_excess().at("joints"), p.start_excess().at("range_of_motion"));
  EXPECT_LE(largest_room, most + 1e-12);
  EXPECT_GT(largest_room, 0.0);
}

// A start sliding sideways out of its feet's boxes (after a push: the base 19 cm aside and moving
// on at 0.45 m/s, the feet standing): the stance feet's offsets grow at 0.45 m/s from 1 cm inside
// their boxes' edges, so the rows after the start get what that motion makes unavoidable, the
// excess at its stop under friction * g (1.1 cm at most here), returning over start_return; before
// this they had no room (the start is within the boxes) and asked the base to stop in 0.02 s. The
// bounds the motion leaves keep theirs (a swinging foot would too: it can accelerate as fast as it
// needs; all four stand at 0.5 s).
TEST(StartReturn, RowsAfterAStartSlidingOutOfItsBoxGetWhatItsMotionMakesUnavoidable) {
  const auto r = hyq();
  FlatField flat;
  const ProblemOptions o = joints_and_box_options();
  Replan sliding = pushed_start(r, flat, o, 0.0, -0.19);
  Replan still = sliding;
  sliding.start.linear_velocity.y() -= 0.45;
  const SrbdProblem p(r, flat, sliding.timeline, o, &sliding.start);
  const SrbdProblem q(r, flat, still.timeline, o, &still.start);
  ASSERT_TRUE(p.start_excess().empty()) << "the start itself is within every box";
  ASSERT_EQ(p.pieces().size(), q.pieces().size());
  const auto& L = p.layout();
  const double span = FeasibilityOptions{}.start_return, decel = o.friction * kGravity;
  // The largest unavoidable excess: each stance foot's offset past its box at its stop.
  double peak = 0.0;
  for (std::size_t f = 0; f < r.legs.size(); ++f) {
    if (L.foot_vel[f][0] >= 0) continue;  // swinging at the start
    const Eigen::Vector3d off =
        rotation_zyx<double>(sliding.start.euler_zyx).transpose() *
            (sliding.start.foot_position[f] - sliding.start.position) -
        r.legs[f].nominal_foot;
    const double v = 0.45 * std::cos(sliding.start.euler_zyx[0]);  // base frame, about
    peak = std::max(peak, off.y() + v * v / (2 * decel) - r.legs[f].range_of_motion.y());
  }
  std::printf("unavoidable excess at most %.4f m\n", peak);
  ASSERT_GT(peak, 0.005);
  int widened = 0, same_after_span = 0;
  double largest_room = 0.0;
  std::set<int> widened_feet, stance_feet;
  for (std::size_t f = 0; f < r.legs.size(); ++f)
    if (L.foot_vel[f][0] < 0) stance_feet.insert(static_cast<int>(f));
  ASSERT_GE(stance_feet.size(), 3u);
  for (std::size_t i = 0; i < p.pieces().size(); ++i) {
    const Piece &a = *p.pieces()[i], &b = *q.pieces()[i];
    ASSERT_EQ(a.kind, b.kind);
    ASSERT_EQ(a.vars, b.vars);
    if (a.kind != "range_of_motion") {
      EXPECT_EQ(a.lb, b.lb) << a.kind;
      EXPECT_EQ(a.ub, b.ub) << a.kind;
      continue;
    }
    const int knot = base_knot_read(L, a, /*last=*/false);
    ASSERT_GE(knot, 0);
    bool differs = false;
    for (int row = 0; row < a.rows(); ++row) {
      EXPECT_EQ(a.lb[row], b.lb[row]) << "nothing moves towards a lower bound";
      EXPECT_GE(a.ub[row], b.ub[row]);
      differs |= a.ub[row] != b.ub[row];
      largest_room = std::max(largest_room, a.ub[row] - b.ub[row]);
    }
    if (differs) {
      ++widened;
      for (std::size_t f = 0; f < r.legs.size(); ++f)
        for (int k = 0; k <= L.num_segments; ++k)
          if (L.foot_pos[f][k] >= 0 &&
              std::find(a.vars.begin(), a.vars.end(), L.foot_pos[f][k]) != a.vars.end())
            widened_feet.insert(static_cast<int>(f));
    }
    if (L.nominal_knot_time[knot] >= span) {
      EXPECT_FALSE(differs) << "knot " << knot;
      ++same_after_span;
    }
  }
  EXPECT_GT(widened, 0);
  EXPECT_GT(same_after_span, 0);
  EXPECT_GT(largest_room, 0.0);
  EXPECT_LE(largest_room, peak + 1e-3);
  EXPECT_EQ(widened_feet, stance_feet);
}

// The changed rows' Jacobians (bounds widened; the rows themselves are the families' own).
TEST(StartReturn, WidenedRowsJacobianMatchesCentralDifferences) {
  const auto r = hyq();
  TanhStep terrain(0.1, 0.5, 0.05, 0.01);
  ProblemOptions o = joints_and_box_options();
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);
  const Replan pushed = pushed_start(r, terrain, o, -0.30, -0.05);
  const SrbdProblem p(r, terrain, pushed.timeline, o, &pushed.start);
  ASSERT_FALSE(p.start_excess().empty());
  EXPECT_GT(check_kind_derivatives(p, "joints"), 0);
  EXPECT_GT(check_kind_derivatives(p, "range_of_motion"), 0);
  ProblemOptions merged = o;
  merged.feasibility_settings = {{"joints_softmax", 0.005}};
  const SrbdProblem m(r, terrain, pushed.timeline, merged, &pushed.start);
  EXPECT_GT(check_kind_derivatives(m, "joints"), 0);
  // A start sliding out of its boxes (the rows' room from its motion).
  Replan sliding = pushed_start(r, terrain, o, 0.0, -0.19);
  sliding.start.linear_velocity.y() -= 0.45;
  const SrbdProblem s(r, terrain, sliding.timeline, o, &sliding.start);
  EXPECT_GT(check_kind_derivatives(s, "range_of_motion"), 0);
}

// The rows widened before a pinned end: their Jacobians (the rows are the families' own). On flat
// ground: on the TanhStep of the start's test the horizon problem's joints rows miss central
// differences by 5e-5 relative at one noisy point, with the end moved or not (room or none).
TEST(StartReturn, RowsBeforeAPinnedEndJacobianMatchesCentralDifferences) {
  const auto r = hyq();
  FlatField terrain;
  ProblemOptions o = joints_and_box_options();
  o.goal = Eigen::Vector3d(0.4, 0.05, 0.3);
  const MovedEnd m = moved_end(r, terrain, o);
  const SrbdProblem p(r, terrain, m.horizon, o, &m.start.start, &m.end);
  ASSERT_TRUE(p.end_excess().count("joints"));
  ASSERT_TRUE(p.end_excess().count("range_of_motion"));
  EXPECT_GT(check_kind_derivatives(p, "joints"), 0);
  EXPECT_GT(check_kind_derivatives(p, "range_of_motion"), 0);
  ProblemOptions merged = o;
  merged.feasibility_settings = {{"joints_softmax", 0.005}};
  const SrbdProblem s(r, terrain, m.horizon, merged, &m.start.start, &m.end);
  EXPECT_GT(check_kind_derivatives(s, "joints"), 0);
}

// The end's room grows over `span` up to the end and is nothing at the end itself and at knot 0,
// whose rows on a measured start are constants: a horizon shorter than `span` (0.5 s against 1 s)
// must not widen them, or part of the start's own excess would go unreported.
TEST(StartReturn, EndRoomIsNothingAtKnotZeroAndAtTheEnd) {
  EXPECT_EQ(end_return_weight(0.0, 0.5, 1.0), 0.0);
  EXPECT_NEAR(end_return_weight(0.25, 0.5, 1.0), 0.75, 1e-12);
  EXPECT_EQ(end_return_weight(0.5, 0.5, 1.0), 0.0);
  EXPECT_EQ(end_return_weight(1.0, 3.0, 1.0), 0.0);  // further from the end than the span
  EXPECT_NEAR(end_return_weight(2.5, 3.0, 1.0), 0.5, 1e-12);
  EXPECT_EQ(end_return_weight(0.25, 0.5, 0.0), 0.0);  // start_return 0: no room
}

}  // namespace
}  // namespace terrastride::planner
