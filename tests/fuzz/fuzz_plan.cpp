// libFuzzer target for plan.json, which `check`, `simulate`, `export`, `report` and the socket's
// plan-taking operations read from a user: the bytes are parsed as read_plan_file parses a file
// (perception::parse_json_input: nesting capped), read by plan_from_json, and the robot
// definition a plan carries (robot_file.yaml) is parsed by robot_of_plan. Every failure must be
// a JSON parse error, a PlanFileError or a RobotFileError; a plan that reads must write and read
// back to the same text. Seeds: tests/fuzz/corpus_plan; the regular suite replays them
// (PlanIo.FuzzCorpusReplay).
#include <cstddef>
#include <cstdint>
#include <string>

#include "terrastride/perception/json_input.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/robot/robot_model.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace pl = terrastride::planner;
  const std::string text(reinterpret_cast<const char*>(data), size);
  pl::Trajectory plan;
  try {
    plan = pl::plan_from_json(terrastride::perception::parse_json_input(text), "in.json");
  } catch (const nlohmann::json::exception&) {
    return 0;
  } catch (const pl::PlanFileError&) {
    return 0;
  }
  const std::string written = pl::plan_text(plan);
  if (pl::plan_text(pl::plan_from_json(nlohmann::json::parse(written), "again.json")) != written)
    __builtin_trap();
  // A plan without a robot definition names a shipped robot, resolved as a path: not the bytes'
  // to choose in a fuzzer.
  if (plan.robot_definition.empty()) return 0;
  try {
    (void)pl::robot_of_plan(plan, "in.json");
  } catch (const pl::PlanFileError&) {
  } catch (const terrastride::robot::RobotFileError&) {
  }
  return 0;
}
