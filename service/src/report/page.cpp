// The report's page: the template, the plotting library and the data, all inline (report.hpp).
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "report/report.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/service/cli.hpp"

#ifndef TERRASTRIDE_REPORT_ASSETS_DIR
#define TERRASTRIDE_REPORT_ASSETS_DIR ""
#endif

namespace terrastride::service::report {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return {};
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Makes text safe inside an inline <script>: no "</" can close the element early.
std::string script_safe(std::string text) {
  std::string out;
  out.reserve(text.size() + 64);
  for (size_t i = 0; i < text.size(); ++i) {
    if (text[i] == '<' && i + 1 < text.size() && (text[i + 1] == '/' || text[i + 1] == '!')) {
      out += "<\\";
      continue;
    }
    out += text[i];
  }
  return out;
}

std::string replace_once(std::string text, const std::string& key, const std::string& value,
                         const std::string& source) {
  const size_t at = text.find(key);
  if (at == std::string::npos)
    throw CommandError(source + ": the placeholder " + key + " is missing");
  text.replace(at, key.size(), value);
  return text;
}

std::string html_escape(const std::string& text) {
  std::string out;
  for (char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

}  // namespace

std::string utc_now() {
  const std::time_t now = std::time(nullptr);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&now));
  return buf;
}

std::string assets_dir() {
  if (const char* env = std::getenv("TERRASTRIDE_REPORT_ASSETS_DIR"); env && *env) return env;
  return TERRASTRIDE_REPORT_ASSETS_DIR;
}

namespace {

struct Assets {
  std::string template_html;
  std::string index_html;
  std::string plotly;
};

const Assets& load_assets() {
  static const Assets assets = [] {
    const std::string dir = assets_dir();
    Assets a;
    const std::string tpl = dir + "/template.html";
    const std::string idx = dir + "/index_template.html";
    const std::string lib = dir + "/node_modules/plotly.js-dist-min/plotly.min.js";
    a.template_html = read_text(tpl);
    if (a.template_html.empty())
      throw CommandError(
          "report template " + tpl +
          " not found (set TERRASTRIDE_REPORT_ASSETS_DIR to the service/report folder)");
    a.index_html = read_text(idx);
    if (a.index_html.empty()) throw CommandError("report index template " + idx + " not found");
    a.plotly = read_text(lib);
    if (a.plotly.empty())
      throw CommandError("the plotting library " + lib +
                         " is not installed: run `npm ci --prefix " + dir +
                         "` (scripts/setup.sh does it)");
    return a;
  }();
  return assets;
}

}  // namespace

std::string render_html(const json& report) {
  const Assets& a = load_assets();
  std::string html = a.template_html;
  html = replace_once(html, "/*__TITLE__*/",
                      html_escape(report.value("title", std::string("report"))), "template.html");
  html = replace_once(html, "/*__PLOTLY__*/", script_safe(a.plotly), "template.html");
  html = replace_once(html, "/*__DATA__*/", script_safe(report.dump()), "template.html");
  return html;
}

std::string render_index_html(const json& index) {
  const Assets& a = load_assets();
  return replace_once(a.index_html, "/*__DATA__*/", script_safe(index.dump()),
                      "index_template.html");
}

std::string write_report(const json& report, const std::string& html_path) {
  fs::path json_path = fs::path(html_path).replace_extension(".json");
  const std::string html = render_html(report);
  perception::write_file_atomically(json_path.string(), report.dump(1) + "\n");
  perception::write_file_atomically(html_path, html);
  return json_path.string();
}

}  // namespace terrastride::service::report
