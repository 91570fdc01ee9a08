// One definition per parameter. Each settings struct of the core lists its
// fields once, in a `.def` file beside its header, one macro call a field:
//
//   SLS_PARAM(type, name, default, min, max, "doc")   a live parameter (int, double or bool)
//   SLS_ENUM(type, name, default, "a:doc|b:doc", "doc") a live string parameter naming an
//                                                       enumerator of `type` (choices in
//                                                       the enumerators' order, from 0)
//   SLS_INT_ENUM(type, name, default, "a:doc|b:doc", "doc") the same as an int parameter
//   SLS_FIXED(type, name, default, "doc")              a setting of the core only
//   SLS_GROUP(type, name, "file.def", "cfg_group")     a nested settings struct (its own
//                                                       .def); its live parameters form
//                                                       the dynamic_reconfigure tab
//   SLS_SECTION(name, type)                            the live parameters after it form a
//                                                       dynamic_reconfigure group (no field)
//
// The struct declares its fields from it (params_struct.inc), and from the
// same lines follow: equality, clamping to [min, max], setting a field by
// name from text (the tools' name=value flags), copying from and to a
// dynamic_reconfigure Config of the same names (the nodelets), the
// dynamic_reconfigure .cfg (cfg/sls_params.py reads the .def) and the
// parameter tables of docs/ (scripts/check-params). So a new parameter is one
// line in a .def, the code that uses it, a test and the regenerated docs.
//
// This header: the helpers that code uses. ROS-free.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdlib>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

namespace structured_light_stabilizer
{
namespace params
{

using Changes = std::vector<std::string>;

// The i-th choice name of "a:doc|b:doc|c" ("" past the end).
inline std::string choiceName(const char* choices, int index)
{
  const std::string all(choices);
  size_t start = 0;
  for (int i = 0; i < index; ++i)
  {
    start = all.find('|', start);
    if (start == std::string::npos)
      return "";
    ++start;
  }
  const size_t end = all.find('|', start);
  const std::string choice = all.substr(start, end == std::string::npos ? std::string::npos : end - start);
  return choice.substr(0, choice.find(':'));
}

// The index of `name` among the choices, -1 when it is none of them.
inline int choiceIndex(const char* choices, const std::string& name)
{
  for (int i = 0;; ++i)
  {
    const std::string c = choiceName(choices, i);
    if (c.empty())
      return -1;
    if (c == name)
      return i;
  }
}

template <typename E>
std::string enumName(const char* choices, E value)
{
  const std::string name = choiceName(choices, static_cast<int>(value));
  return name.empty() ? "unknown" : name;
}

// false (and *value untouched) when `name` is not a choice.
template <typename E>
bool enumFromName(const char* choices, const std::string& name, E* value)
{
  const int i = choiceIndex(choices, name);
  if (i < 0)
    return false;
  *value = static_cast<E>(i);
  return true;
}

template <typename E>
bool enumFromIndex(const char* choices, int index, E* value)
{
  if (index < 0 || choiceName(choices, index).empty())
    return false;
  *value = static_cast<E>(index);
  return true;
}

// Clamps *v into [lo, hi] (a value that is not finite goes to lo) and says so.
template <typename T>
void clampTo(T* v, T lo, T hi, const char* name, Changes* changes)
{
  T c = *v < lo ? lo : (*v > hi ? hi : *v);
  if constexpr (std::is_floating_point<T>::value)
    if (!std::isfinite(*v))
      c = lo;
  if (c != *v)
  {
    std::ostringstream s;
    s << name << " " << *v << " out of [" << lo << ", " << hi << "], clamped to " << c;
    changes->push_back(s.str());
    *v = c;
  }
}
inline void clampTo(bool*, bool, bool, const char*, Changes*) {}

// A value as text ("1.5", "3", "true"/"false"/"1"/"0") into a field; false
// when it does not read as the field's type.
inline bool parseInto(const std::string& text, double* v)
{
  char* end = nullptr;
  const double x = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0')
    return false;
  *v = x;
  return true;
}
inline bool parseInto(const std::string& text, int* v)
{
  char* end = nullptr;
  const long x = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0')
    return false;
  *v = static_cast<int>(x);
  return true;
}
inline bool parseInto(const std::string& text, bool* v)
{
  if (text == "1" || text == "true")
    return (*v = true, true);
  if (text == "0" || text == "false")
    return (*v = false, true);
  return false;
}

}  // namespace params
}  // namespace structured_light_stabilizer
