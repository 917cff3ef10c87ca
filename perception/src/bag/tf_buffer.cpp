#include "terrastride/perception/tf_buffer.hpp"

#include <algorithm>
#include <cstdio>
#include <set>

namespace terrastride::perception {

std::string format_stamp(int64_t t) {
  char buf[48];
  const int64_t s = t >= 0 ? t / 1000000000 : -((-t + 999999999) / 1000000000);
  const int64_t ns = t - s * 1000000000;
  std::snprintf(buf, sizeof buf, "%lld.%09lld", static_cast<long long>(s), static_cast<long long>(ns));
  return buf;
}

void TfBuffer::add(const TransformSample& sample, bool is_static) {
  if (sample.child.empty() || sample.parent.empty())
    throw InputError("a transform with an empty frame name ('" + sample.parent + "' -> '" +
                     sample.child + "')");
  if (sample.child == sample.parent)
    throw InputError("a transform from frame '" + sample.child + "' to itself");
  auto [it, inserted] = links_by_child_.try_emplace(sample.child);
  Link& link = it->second;
  if (inserted) {
    link.parent = sample.parent;
    link.is_static = is_static;
  } else if (link.parent != sample.parent) {
    throw InputError("frame '" + sample.child + "' has two parents, '" + link.parent + "' and '" +
                     sample.parent + "' (a tf tree gives each frame one)");
  }
  if (is_static) {
    // /tf_static is latched: the latest message holds for all time.
    link.is_static = true;
    link.samples.assign(1, {sample.stamp_ns, sample.parent_from_child});
    return;
  }
  if (link.is_static) return;  // a static link stays static (tf2 prefers the static one too)
  auto& s = link.samples;
  auto pos = std::upper_bound(s.begin(), s.end(), sample.stamp_ns,
                              [](int64_t t, const auto& e) { return t < e.first; });
  s.insert(pos, {sample.stamp_ns, sample.parent_from_child});
}

std::vector<std::string> TfBuffer::frames() const {
  std::set<std::string> names;
  for (const auto& [child, link] : links_by_child_) {
    names.insert(child);
    names.insert(link.parent);
  }
  return {names.begin(), names.end()};
}

std::vector<std::string> TfBuffer::describe() const {
  std::vector<std::string> out;
  for (const auto& [child, link] : links_by_child_)
    out.push_back(link.parent + " -> " + child + " (" +
                  (link.is_static ? std::string("static")
                                  : std::to_string(link.samples.size()) + " samples") +
                  ")");
  return out;
}

std::vector<std::string> TfBuffer::chain(const std::string& frame) const {
  std::vector<std::string> c{frame};
  std::set<std::string> seen{frame};
  for (auto it = links_by_child_.find(frame); it != links_by_child_.end();
       it = links_by_child_.find(c.back())) {
    if (!seen.insert(it->second.parent).second)
      throw InputError("the tf frames form a loop through '" + it->second.parent + "'");
    c.push_back(it->second.parent);
  }
  return c;
}

Eigen::Isometry3d TfBuffer::link_at(const std::string& child, const Link& link, int64_t t,
                                    const std::string& target, const std::string& source) const {
  const auto& s = link.samples;
  if (link.is_static) return s.front().second;
  const auto fail = [&](const std::string& why) {
    throw InputError("no transform from frame '" + source + "' to '" + target + "' at t = " +
                     format_stamp(t) + " s: the link " + link.parent + " -> " + child + " " + why);
  };
  if (s.empty()) fail("has no samples");
  if (t < s.front().first || t > s.back().first)
    fail("is known from " + format_stamp(s.front().first) + " to " +
         format_stamp(s.back().first) + " s only (tf does not extrapolate)");
  auto hi = std::lower_bound(s.begin(), s.end(), t,
                             [](const auto& e, int64_t v) { return e.first < v; });
  if (hi->first == t) return hi->second;
  auto lo = hi - 1;
  const double a = static_cast<double>(t - lo->first) / static_cast<double>(hi->first - lo->first);
  Eigen::Isometry3d r = Eigen::Isometry3d::Identity();
  r.translation() = (1 - a) * lo->second.translation() + a * hi->second.translation();
  const Eigen::Quaterniond q0(lo->second.linear()), q1(hi->second.linear());
  r.linear() = q0.slerp(a, q1).toRotationMatrix();
  return r;
}

Eigen::Isometry3d TfBuffer::lookup(const std::string& target, const std::string& source,
                                   int64_t t) const {
  if (target == source) return Eigen::Isometry3d::Identity();
  const auto known = [&](const std::string& f) {
    if (links_by_child_.count(f)) return true;
    for (const auto& [c, l] : links_by_child_)
      if (l.parent == f) return true;
    return false;
  };
  for (const std::string& f : {source, target})
    if (!known(f)) {
      std::string all;
      for (const auto& n : frames()) all += (all.empty() ? "" : ", ") + n;
      throw InputError("no transform from frame '" + source + "' to '" + target + "' at t = " +
                       format_stamp(t) + " s: no /tf or /tf_static message names frame '" + f +
                       "' (frames: " + (all.empty() ? "none" : all) + ")");
    }
  const std::vector<std::string> up_source = chain(source), up_target = chain(target);
  // The lowest common ancestor: the first frame of source's chain that target's chain holds.
  size_t i_common = up_source.size();
  size_t j_common = 0;
  for (size_t i = 0; i < up_source.size() && i_common == up_source.size(); ++i)
    for (size_t j = 0; j < up_target.size(); ++j)
      if (up_source[i] == up_target[j]) {
        i_common = i;
        j_common = j;
        break;
      }
  if (i_common == up_source.size())
    throw InputError("no transform from frame '" + source + "' to '" + target + "' at t = " +
                     format_stamp(t) + " s: they are in different tf trees (roots '" +
                     up_source.back() + "' and '" + up_target.back() + "')");
  Eigen::Isometry3d common_from_source = Eigen::Isometry3d::Identity();
  for (size_t i = 0; i < i_common; ++i)
    common_from_source = link_at(up_source[i], links_by_child_.at(up_source[i]), t, target, source) *
                         common_from_source;
  Eigen::Isometry3d common_from_target = Eigen::Isometry3d::Identity();
  for (size_t j = 0; j < j_common; ++j)
    common_from_target = link_at(up_target[j], links_by_child_.at(up_target[j]), t, target, source) *
                         common_from_target;
  return common_from_target.inverse() * common_from_source;
}

}  // namespace terrastride::perception
