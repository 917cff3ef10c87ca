#include "json_reader.hpp"

#include <fstream>

#include "terrastride/perception/json_input.hpp"

namespace terrastride::planner::io {

// The JSON document in `path`; `what` names the file's role in the error when it cannot be opened.
json read_json_file(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw PlanFileError(path + ": cannot open " + what);
  try {
    return perception::parse_json_input(in);
  } catch (const json::exception& e) {  // parse errors, too deep, numbers beyond double (1e999)
    throw PlanFileError(path + ": not valid JSON: " + e.what());
  }
}

}  // namespace terrastride::planner::io
