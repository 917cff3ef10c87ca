// plan.json on disk: written atomically, read with every field validated.
#include <unistd.h>

#include <cstdio>
#include <fstream>

#include "json_reader.hpp"
#include "terrastride/planner/plan_io.hpp"

namespace terrastride::planner {

void write_plan_file(const std::string& path, const Trajectory& trajectory) {
  const std::string text = plan_to_json(trajectory).dump(1) + "\n";
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) throw PlanFileError(path + ": cannot write (directory missing or not writable)");
    out << text;
    out.flush();
    if (!out) {
      std::remove(tmp.c_str());
      throw PlanFileError(path + ": write failed (disk full?)");
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw PlanFileError(path + ": cannot move the finished plan into place");
  }
}

Trajectory read_plan_file(const std::string& path) {
  return plan_from_json(io::read_json_file(path, "plan file"), path);
}

}  // namespace terrastride::planner
