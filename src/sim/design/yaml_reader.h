// A strict reader of YAML settings for the rig files (rig_yaml.cpp,
// rig_design_inputs.cpp): keys checked against the known ones, numbers,
// lists, words and booleans, each error a std::invalid_argument naming
// "<what>: <source>:<line>: <reason>". Internal to the sim library.
#pragma once

#include <cmath>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

namespace structured_light_stabilizer
{
namespace sim
{

struct YamlReader
{
  std::string what;    // the message's prefix: "rig", "rig_design"
  std::string source;  // the file (or "<string>")

  [[noreturn]] void refuse(const YAML::Node& node, const std::string& reason) const
  {
    const YAML::Mark m = node.Mark();
    const std::string at = m.line < 0 ? source : source + ":" + std::to_string(m.line + 1);
    throw std::invalid_argument(what + ": " + at + ": " + reason);
  }

  // Refuses a node that is not a mapping, and keys not in `known`.
  void onlyKeys(const YAML::Node& node, const std::string& section, const std::set<std::string>& known) const
  {
    if (!node.IsMap())
      refuse(node, section + " must be a mapping");
    std::string list;
    for (const auto& k : known)
      list += (list.empty() ? "" : ", ") + k;
    for (const auto& kv : node)
      if (!known.count(kv.first.as<std::string>()))
        refuse(kv.first, "unknown key '" + section + "." + kv.first.as<std::string>() + "' (known: " + list + ")");
  }

  // node[key] x scale into *v when present.
  void number(const YAML::Node& node, const char* key, double scale, double* v) const
  {
    const YAML::Node n = node[key];
    if (n)
      *v = scalar(n, key) * scale;
  }

  void integer(const YAML::Node& node, const char* key, int* v) const
  {
    double x = *v;
    number(node, key, 1.0, &x);
    if (x != std::floor(x) || std::fabs(x) > 1e6)
      refuse(node[key], std::string(key) + " must be an integer");
    *v = static_cast<int>(x);
  }

  // A non-empty list of numbers, each x scale.
  void numbers(const YAML::Node& node, const char* key, double scale, std::vector<double>* v) const
  {
    const YAML::Node n = node[key];
    if (!n)
      return;
    if (!n.IsSequence() || n.size() == 0)
      refuse(n, std::string(key) + " must be a non-empty list of numbers");
    v->clear();
    for (const auto& item : n)
      v->push_back(scalar(item, key) * scale);
  }

  void boolean(const YAML::Node& node, const char* key, bool* v) const
  {
    const YAML::Node n = node[key];
    if (n && (!n.IsScalar() || !YAML::convert<bool>::decode(n, *v)))
      refuse(n, std::string(key) + " must be true or false");
  }

  void booleans(const YAML::Node& node, const char* key, std::vector<bool>* v) const
  {
    const YAML::Node n = node[key];
    if (!n)
      return;
    if (!n.IsSequence() || n.size() == 0)
      refuse(n, std::string(key) + " must be a non-empty list of true/false");
    v->clear();
    for (const auto& item : n)
    {
      bool b = false;
      if (!item.IsScalar() || !YAML::convert<bool>::decode(item, b))
        refuse(item, std::string(key) + " must hold true or false");
      v->push_back(b);
    }
  }

  // A word out of `choices`, as its index; -1 when absent.
  int word(const YAML::Node& node, const char* key, const std::vector<std::string>& choices) const
  {
    const YAML::Node n = node[key];
    if (!n)
      return -1;
    const std::string s = n.IsScalar() ? n.Scalar() : "";
    for (size_t i = 0; i < choices.size(); ++i)
      if (s == choices[i])
        return static_cast<int>(i);
    std::string list;
    for (const auto& c : choices)
      list += (list.empty() ? "" : " | ") + c;
    refuse(n, std::string(key) + " must be one of " + list);
  }

private:
  double scalar(const YAML::Node& n, const char* key) const
  {
    double x = 0.0;
    if (!n.IsScalar() || !YAML::convert<double>::decode(n, x) || !std::isfinite(x))
      refuse(n, std::string(key) + " must be a finite number (or a list of them)");
    return x;
  }
};

}  // namespace sim
}  // namespace structured_light_stabilizer
