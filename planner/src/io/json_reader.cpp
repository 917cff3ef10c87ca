#include "json_reader.hpp"

#include <fstream>

namespace terrastride::planner::io {

// The JSON document in `path`; `what` names the file's role in the error when it cannot be opened.
json read_json_file(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw PlanFileError(path + ": cannot open " + what);
  try {
    return json::parse(in);
  } catch (const json::exception& e) {  // parse errors, and numbers beyond double (1e999)
    throw PlanFileError(path + ": not valid JSON: " + e.what());
  }
}

}  // namespace terrastride::planner::io
