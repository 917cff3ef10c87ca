// plan.json on disk: written atomically (perception::write_file_atomically), read with every
// field validated.
#include "json_reader.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/planner/plan_io.hpp"

namespace terrastride::planner {

void write_plan_file(const std::string& path, const Trajectory& trajectory,
                     const SerialisedSamples* samples) {
  // perception's writer: a regular file (also behind a symbolic link, which stays) is replaced
  // atomically, a FIFO or device is written through, /dev/stdout is the process's descriptor.
  try {
    perception::write_file_atomically(path, plan_text(trajectory, samples));
  } catch (const perception::InputError& e) {
    throw PlanFileError(e.what());
  }
}

Trajectory read_plan_file(const std::string& path) {
  return plan_from_json(io::read_json_file(path, "plan file"), path);
}

}  // namespace terrastride::planner
